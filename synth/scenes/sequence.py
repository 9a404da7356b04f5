"""The pattern sequence: phase-shift fringes (DESIGN.md definition), Gray code, white, black and
user images, expanded into one ``PatternSpec`` per projected image, named as in the capture
layout (``v_f048_n11``, ``white``, ``v_gray_b03``, ...).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from unwrap.patterns import fringe_pattern

from unwrap.strict import check_keys

from ..errors import SynthError

KINDS = ("phase", "gray", "white", "black", "image")


@dataclass(frozen=True, eq=False)
class PatternSpec:
    """One projected image. ``kind``: fringe / gray / white / black / image."""

    name: str
    kind: str
    orientation: str = ""
    frequency: float = 0.0
    step: int = 0
    steps: int = 0
    bit: int = 0
    bits: int = 0
    inverse: bool = False
    image: np.ndarray | None = None   # (H_p, W_p) float64 in [0, 1] for kind "image"
    block: int = 1                    # gray: projector pixels per code step

    def projector_image(self, size, A: float, B: float) -> np.ndarray:
        """The (H_p, W_p) float64 image this pattern puts on the projector, in [0, 1]."""
        W, H = size
        if self.kind == "fringe":
            return fringe_pattern(size, self.frequency, self.step, self.steps, self.orientation, A, B)
        if self.kind == "white":
            return np.ones((H, W))
        if self.kind == "black":
            return np.zeros((H, W))
        if self.kind == "gray":
            n = W if self.orientation == "v" else H
            idx = np.arange(n) // self.block
            code = ((idx ^ (idx >> 1)) >> (self.bits - 1 - self.bit)) & 1
            code = (1 - code) if self.inverse else code
            line = code.astype(np.float64)
            return np.broadcast_to(line[None, :] if self.orientation == "v" else line[:, None], (H, W)).copy()
        if self.kind == "image":
            return self.image
        raise SynthError(f"pattern {self.name}: unknown kind {self.kind!r}")


def frequency_tag(f: float) -> str:
    return f"f{int(f):03d}" if float(f).is_integer() else f"f{f:g}".replace(".", "p")


def fringe_name(orientation: str, frequency: float, step: int) -> str:
    return f"{orientation}_{frequency_tag(frequency)}_n{step:02d}"


#: The most fringe images one sequence may ask for (far above any real ladder: 2 x 3 x 36 = 216).
MAX_IMAGES = 10000


def phase_sequence(orientations=("v", "h"), frequencies=(1, 8, 48), steps=12) -> list[PatternSpec]:
    """Phase-shift fringes for each orientation and frequency (``steps``: int or one per frequency)."""
    steps_list = [steps] * len(frequencies) if isinstance(steps, int) else list(steps)
    if len(steps_list) != len(frequencies):
        raise SynthError(f"patterns: steps {steps_list} and frequencies {list(frequencies)} differ in length")
    check_frequencies(frequencies)
    total = len(orientations) * sum(int(n) if isinstance(n, int) else 0 for n in steps_list)
    if total > MAX_IMAGES:   # refused before millions of pattern descriptions are built
        raise SynthError(f"patterns: {total} fringe images ({len(orientations)} orientation(s) x steps {steps_list}); "
                         f"at most {MAX_IMAGES} per sequence")
    out = []
    for o in orientations:
        if o not in ("v", "h"):
            raise SynthError(f"patterns.orientation: expected 'v', 'h' or 'both', got {o!r}")
        for f, n in zip(frequencies, steps_list):
            if not (isinstance(f, (int, float)) and f > 0 and math.isfinite(f)):
                raise SynthError(f"patterns.frequencies: expected positive numbers, got {f!r}")
            if not (isinstance(n, int) and n >= 3):
                raise SynthError(f"patterns.steps: expected integers >= 3, got {n!r}")
            out += [PatternSpec(fringe_name(o, f, k), "fringe", o, float(f), k, n) for k in range(n)]
    return out


def check_frequencies(frequencies, key: str = "patterns.frequencies") -> None:
    """Refuse (:class:`SynthError`) a fringe ladder with a repeated frequency (equal to 1e-9,
    e.g. ``8`` and ``8.0``: the same images twice under the same file names). One check for
    ``calib render``, ``calib render-board`` and the dataset export (:func:`phase_sequence`)."""
    fs = [float(f) for f in frequencies if isinstance(f, (int, float)) and not isinstance(f, bool)]
    for i, f in enumerate(fs):
        if any(math.isclose(f, g, rel_tol=1e-9) for g in fs[:i]):
            raise SynthError(f"{key}: frequency {f:g} is given twice in {list(frequencies)}; give each frequency once")


def check_fringe_periods(patterns, projector_size) -> None:
    """Refuse (:class:`SynthError`) a fringe whose period is under 2 projector pixels (``v``:
    across the width, ``h``: the height of ``projector_size`` (W, H)): such a pattern aliases on
    the projector (e.g. 2000 periods across 912 px, a 0.46 px period). Checked by
    :func:`synth.renderer.render.render` before any work, so for every command that renders."""
    for p in patterns:
        if p.kind != "fringe":
            continue
        extent = projector_size[0] if p.orientation == "v" else projector_size[1]
        if extent / p.frequency < 2.0:
            raise SynthError(f"patterns.frequencies: frequency {p.frequency:g} ({p.orientation}) has a period of "
                             f"{extent / p.frequency:.2f} projector px across {extent} px; under 2 px the fringes "
                             f"alias: at most {extent / 2:g} periods")


def gray_sequence(orientation: str, size, bits: int | None = None, inverse: bool = False,
                  block: int = 1) -> list[PatternSpec]:
    """Gray code bit planes (MSB first) of projector column (``v``) or row (``h``) block indices
    (``block`` projector pixels per code step; OpenCV's GrayCodePattern with block 1), named as the
    Gray-code capture layout reads them (``v_gray_b03``, ``v_gray_b03_inv``)."""
    if not (isinstance(block, int) and block >= 1):
        raise SynthError(f"gray code block: expected an integer >= 1 (projector px), got {block!r}")
    n = -(-(size[0] if orientation == "v" else size[1]) // block)
    bits = int(bits) if bits else max(1, math.ceil(math.log2(n)))
    out = [PatternSpec(f"{orientation}_gray_b{b:02d}", "gray", orientation, bit=b, bits=bits, block=block)
           for b in range(bits)]
    if inverse:
        out += [PatternSpec(f"{orientation}_gray_b{b:02d}_inv", "gray", orientation, bit=b, bits=bits, inverse=True,
                            block=block) for b in range(bits)]
    return out


def _orientations(value, key):
    if value in ("both", None):
        return ("v", "h")
    if value in ("v", "h"):
        return (value,)
    raise SynthError(f"{key}.orientation: expected 'v', 'h' or 'both', got {value!r}")


def sequence_from_tables(entries, projector_size, base_dir: Path = Path(".")) -> list[PatternSpec]:
    """``[[patterns.sequence]]`` tables -> PatternSpecs. Names must be unique."""
    if not isinstance(entries, list) or not entries:
        raise SynthError("patterns.sequence: expected a non-empty list of tables")
    out: list[PatternSpec] = []
    for i, e in enumerate(entries):
        key = f"patterns.sequence[{i}]"
        if not isinstance(e, dict) or "kind" not in e:
            raise SynthError(f"{key}: expected a table with a 'kind' ({', '.join(KINDS)})")
        kind = e["kind"]
        allowed = {"phase": {"kind", "orientation", "frequencies", "steps"},
                   "gray": {"kind", "orientation", "bits", "inverse", "block_px"},
                   "white": {"kind", "name"}, "black": {"kind", "name"},
                   "image": {"kind", "file", "name"}}.get(kind)
        if allowed is None:
            raise SynthError(f"{key}.kind: expected one of {KINDS}, got {kind!r}")
        check_keys(e, allowed, f"scene (kind {kind!r})", SynthError, prefix=f"{key}.")
        if kind == "phase":
            if "frequencies" not in e:
                raise SynthError(f"{key}.frequencies: missing (e.g. [1, 8, 48])")
            out += phase_sequence(_orientations(e.get("orientation", "both"), key), list(e["frequencies"]),
                                  e.get("steps", 12))
        elif kind == "gray":
            for o in _orientations(e.get("orientation", "both"), key):
                out += gray_sequence(o, projector_size, e.get("bits"), bool(e.get("inverse", False)),
                                     e.get("block_px", 1))
        elif kind in ("white", "black"):
            out.append(PatternSpec(e.get("name", kind), kind))
        else:
            if "file" not in e:
                raise SynthError(f"{key}.file: missing (a PNG/TIFF of the projector's size)")
            out.append(PatternSpec(e.get("name", Path(e["file"]).stem), "image",
                                   image=read_pattern_image(base_dir / e["file"], projector_size, f"{key}.file")))
    names = [p.name for p in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise SynthError(f"patterns.sequence: duplicate pattern names {dup}")
    return out


def read_pattern_image(path, projector_size, key: str) -> np.ndarray:
    """Grey image file of the projector's size -> (H_p, W_p) float64 in [0, 1]."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise SynthError(f"{key}: cannot read image {path}")
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    W, H = projector_size
    if img.shape != (H, W):
        raise SynthError(f"{key}: image {path} is {img.shape[1]}x{img.shape[0]}, the projector is {W}x{H}")
    scale = float(np.iinfo(img.dtype).max) if np.issubdtype(img.dtype, np.integer) else 1.0
    return np.clip(img.astype(np.float64) / scale, 0.0, 1.0)
