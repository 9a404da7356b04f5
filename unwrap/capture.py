"""Read fringe captures from disk: the DESIGN.md layout and three real scanners' own layouts.

A capture is described per orientation ("v": fringes along projector columns -> u_p, "h" -> v_p)
by :class:`FringeSet` items (frames of one frequency with their shifts) and optional Gray-code
frames. Layouts:

- ``design`` (DESIGN.md): ``capture.toml`` with ``[pattern] steps, frequencies`` and
  ``[projector] size``; frames ``{v|h}_f{FFF}_n{NN}.png`` in the folder (or in its first pose
  folder ``pose_00``; ``pose=`` picks another). A frame of that naming which the description does
  not account for (``v_f048_n12.png`` beside ``steps = 12``) is refused: the step count is wrong.
  Captures written in another convention declare it in ``[pattern]`` (:func:`design_shifts`):
  ``shift_sign = -1`` for ``A + B cos(Phi + 2 pi n/N)``, ``phase_offset`` (rad) for frames
  ``A + B cos(Phi + phase_offset - delta_n)`` (pi: the pattern starts dark), or explicit
  ``shifts`` (rad, one list per frequency).
- ``slstudio`` (jakobwilm/slstudio example data): ``frameSeq_00..11.png``; 3-step, 16 periods +
  1-period cue per orientation, projector 1824 x 1140 (6 frames: columns only).
- ``slmaster`` (Practice3DVision/SLMaster monocular data): ``L/0..17.png``; 12-step, 32 periods
  of 60 px on a 1920-px DMD, shifts ``pi - 2 pi n/12`` in our convention, then 5+1 bits of
  complementary Gray code thresholded against the background A.

  Both read ``.bmp`` (what the two tools write) or ``.tif`` frames of the same names too.
- ``kamino-phaseshift`` (kamino410/phase-shifting sample; formerly ``kamino``, still accepted):
  ``pat00..31.png`` + ``config.xml``; 3-step at periods 200/3 and 100 px (shifts +2pi/3, 0,
  -2pi/3), OpenCV Gray code (pattern, inverse) pairs on 100-px blocks, white and black frames.
- Gray code only (no phase shifting; :mod:`unwrap.graycode_capture`): the DESIGN.md layout with
  ``[pattern] kind = "graycode"``, and ``procam-graycode`` (kamino410/procam-calibration's
  ``capture_*/graycode_NN.png``, OpenCV's frame order; the projector size comes from the
  ``description`` - the capture.toml - since the frame count does not fix it). Frames named like
  the layout's that the description does not account for are refused here too.

The preset is taken from ``capture.toml`` (``[capture] preset = "..."``), the ``preset``
argument, or recognised from the files present.
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import UnwrapError
from .graycode_capture import GRAY_KIND, design_gray_orientations, procam_orientations, read_gray_pattern
from .strict import check_table, read_toml_text

PRESETS = ("design", "slstudio", "slmaster", "kamino-phaseshift", "procam-graycode")
PRESET_ALIASES = {"kamino": "kamino-phaseshift"}
"""Former preset names, still read: ``kamino`` named the author, not the layout (a phase-shift +
Gray-block capture; the same author's Gray-code calibration tool is ``procam-graycode``)."""


@dataclass
class FringeSet:
    """Frames of one fringe frequency: ``files`` (N paths), ``shifts`` (N, rad), ``frequency``."""
    frequency: float
    files: list
    shifts: np.ndarray


@dataclass
class OrientationCapture:
    """Everything one orientation needs: fringe sets, the pattern width and optional Gray code.

    gray: None or dict(kind="complementary"|"opencv", files=[...], inverse=[...] or None,
    block_px=..., n_bits=...).
    """
    orientation: str
    width: float
    sets: list
    gray: dict | None = None
    white: Path | None = None
    black: Path | None = None


#: Where ``calib run`` looks for the board, in order (``[capture] board_image``).
BOARD_IMAGE_SOURCES = ("white", "background", "modulation")


@dataclass
class Capture:
    """A capture folder and its description, parsed once: the one type of a capture session
    (``calib.detect.captures.read_session``: board, poses, sizes) and of one pose's frames
    (:func:`load_capture`: orientations).

    - folder: the capture (or pose) folder; preset: its frame layout; default_method: the
      preset's (or the description's) temporal unwrapping method.
    - orientations: {"v"|"h": OrientationCapture} of the frames (empty for a session).
    - camera_size, projector_size: (W, H) px where the description states them.
    - toml: the description's path; description: the capture.toml as a dict (read once, passed on
      to the pose loads); method: ``[capture] method`` (None when absent).
    - poses: [(name, folder)] one per board pose; board_image: board detection sources in order;
      board: the printed board (a ``calib.board.Board``, set by calib's reader).
    """
    folder: Path
    preset: str
    orientations: dict = field(default_factory=dict)
    default_method: str = "mf"
    camera_size: tuple | None = None
    projector_size: tuple | None = None
    toml: Path | None = None
    description: dict = field(default_factory=dict)
    method: str | None = None
    poses: list = field(default_factory=list)
    board_image: tuple = BOARD_IMAGE_SOURCES
    board: object = None


def read_image(path) -> np.ndarray:
    """Grey image as a 2-D array of its own dtype (8/16-bit PNG/TIFF/BMP)."""
    import cv2
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"capture frame not found: {path}")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise UnwrapError(f"cannot read image {path}")
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.dtype not in (np.uint8, np.uint16):
        what = f"{img.dtype} frame"
        if img.dtype.kind == "f":
            finite = np.isfinite(img)
            bad = img.size - int(np.count_nonzero(finite))
            what = f"floating-point ({img.dtype}) frame" + (f" with {bad} NaN/inf pixel(s)" if bad else "")
            if bad < img.size:
                what += f", values {float(img[finite].min()):.4g} to {float(img[finite].max()):.4g}"
        raise UnwrapError(f"{path}: {what}; capture frames must be 8- or 16-bit integer grey levels as the camera "
                          "gave them (the modulation threshold is a share of their full scale): save them as 8/16-bit "
                          "PNG or TIFF")
    return img


def check_distinct_frames(stack: np.ndarray, files) -> None:
    """Refuse (:class:`UnwrapError` naming both files) a phase-shift stack (N, H, W) in which two
    frames are identical or nearly so (a frame saved twice, a step that did not move): they are
    never a phase shift apart, and the decoded phase would be off by up to pi/N with nothing but a
    high noise figure to show it. Near-identical: the mean absolute difference of the two frames is
    under a quarter of what their phase shift gives (the stack's median of difference / |sin(pi
    (j - i) / N)|, frames in step order); a stack without fringes (all dark) is left to the
    modulation threshold."""
    n = len(stack)
    if n < 3:
        return
    step = max(1, int(np.ceil(np.sqrt(stack[0].size / 65536.0))))   # a subsample of about 65k pixels
    sub = stack[:, ::step, ::step].astype(np.float64)
    d = {(i, j): float(np.mean(np.abs(sub[i] - sub[j]))) for i in range(n) for j in range(i + 1, n)}
    shift = {(i, j): abs(np.sin(np.pi * (j - i) / n)) for i, j in d}
    scale = float(np.median([d[k] / shift[k] for k in d if shift[k] > 1e-9]))
    if scale < 0.5:                      # no fringes at all (half a grey level)
        return
    for (i, j), dij in d.items():
        if dij == 0.0 or dij < 0.25 * scale * shift[(i, j)]:
            how = "identical" if dij == 0.0 else (f"nearly identical (mean difference {dij:.3g} grey levels, a "
                                                  f"{2 * (j - i)}pi/{n} shift gives about {scale * shift[(i, j)]:.3g})")
            raise UnwrapError(f"{files[j]}: {how} to {files[i]}; the frames of a phase-shift stack must each be "
                              f"shifted by 2 pi/{n}: a frame saved twice or a step that did not move (check the "
                              "capture)")


_AHEAD: dict = {}
"""Frames being decoded ahead of their turn: {path: Future of :func:`read_image`} (:func:`prefetch`).
Forgotten in a forked child, whose copy of the pool has no threads to finish them."""
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_AHEAD.clear)


def prefetch(files) -> None:
    """Start decoding ``files`` on the pool now (the next orientation's frames while this one is
    decoded); :func:`read_images` then takes the decoded frame, or the error, when its turn comes.
    :func:`forget_prefetched` drops what was never asked for."""
    from ._threads import pool

    for f in files:
        if f not in _AHEAD:
            _AHEAD[f] = pool("read-frames").submit(read_image, f)


def forget_prefetched(files=None) -> None:
    """Drop the frames :func:`prefetch` decoded for ``files`` (default: all) and nobody read."""
    for f in list(_AHEAD) if files is None else files:
        _AHEAD.pop(f, None)


def read_images(files):
    """:func:`read_image` of each of ``files``, decoded on a thread pool (OpenCV's decoders release
    the GIL; :mod:`unwrap._threads`) and yielded in order; a frame that cannot be read raises when
    its turn comes. Frames :func:`prefetch` started are taken from there (once)."""
    from ._threads import pool

    files = list(files)
    ahead = [_AHEAD.pop(f, None) for f in files]
    if not any(ahead):
        return pool("read-frames").map(read_image, files)
    rest = iter(pool("read-frames").map(read_image, [f for f, a in zip(files, ahead) if a is None]))
    return (a.result() if a is not None else next(rest) for a in ahead)


class FrameReader:
    """Reads the frames of one capture, checking each against the first one read.

    Refused (UnwrapError naming the frame): a frame of another bit depth (one 16-bit frame among
    8-bit ones decodes to garbage) or size than the first, and a first frame whose size
    contradicts ``camera_size`` (W, H) from the capture's description. Phase-shift, Gray-code,
    white and black frames of a capture go through the same reader."""

    def __init__(self, camera_size=None):
        self.camera_size = None if camera_size is None else tuple(camera_size)
        self.first = None   # (path, dtype, shape) of the first frame read

    def image(self, path) -> np.ndarray:
        return self.check(path, read_image(path))

    def check(self, path, img: np.ndarray) -> np.ndarray:
        """``img`` (read from ``path``) checked against the first frame (class docstring)."""
        if self.first is None:
            self.first = (path, img.dtype, img.shape)
            if self.camera_size is not None and (img.shape[1], img.shape[0]) != self.camera_size:
                raise UnwrapError(f"{path}: frame is {img.shape[1]}x{img.shape[0]}, capture.toml [camera] "
                                  f"size says {self.camera_size[0]}x{self.camera_size[1]}")
            return img
        first, dtype, shape = self.first
        if img.dtype != dtype:
            raise UnwrapError(f"{path}: {img.dtype} frame among {dtype} frames (first: {first}): "
                              "every frame of a capture must have the same bit depth")
        if img.shape != shape:
            raise UnwrapError(f"{path}: frame is {img.shape[1]}x{img.shape[0]}, {first} is "
                              f"{shape[1]}x{shape[0]}: every frame must have the same size")
        return img

    def stack(self, files) -> np.ndarray:
        """(N, H, W) stack of ``files``, each checked in order (decoded on threads:
        :func:`read_images`; the first bad frame in order is the one named)."""
        files = list(files)
        out = None
        for i, (f, img) in enumerate(zip(files, read_images(files))):
            img = self.check(f, img)
            if out is None:
                out = np.empty((len(files), *img.shape), img.dtype)
            out[i] = img
        if out is None:
            raise UnwrapError("no frames to read")
        return out

    def phase_stack(self, files) -> np.ndarray:
        """:meth:`stack` of a phase-shift set, whose frames must also differ
        (:func:`check_distinct_frames`)."""
        stack = self.stack(files)
        check_distinct_frames(stack, list(files))
        return stack


def read_stack(files) -> np.ndarray:
    """(N, H, W) stack of ``files`` in their own dtype; frames of mixed bit depth or size are
    refused (:class:`FrameReader`)."""
    return FrameReader().stack(files)


#: The keys and types of a ``capture.toml`` (DESIGN.md); the strict reader (:mod:`unwrap.strict`)
#: refuses any other key naming the closest known one. ``[board]`` is checked by
#: ``calib.board.Board.from_dict``, ``[render]`` (what rendered the capture) is free.
CAPTURE_SCHEMA = {
    "board": dict,
    "pattern": {"kind": str, "steps": int | tuple[int, ...], "frequencies": tuple[float, ...], "shift_sign": int,
                "phase_offset": float, "shifts": tuple[float, ...] | tuple[tuple[float, ...], ...],
                "block_px": int, "inverse": bool},
    "camera": {"size": tuple[int, ...]},
    "projector": {"size": tuple[int, ...]},
    "capture": {"preset": str, "method": str, "poses": tuple[str, ...], "board_image": tuple[str, ...]},
    "render": dict,
}


def read_toml(path) -> dict:
    """A capture description as a dict; UnwrapError naming the file when it is not valid TOML, has
    a key :data:`CAPTURE_SCHEMA` does not know (naming the closest) or a value of the wrong type."""
    return check_table(read_toml_text(path, UnwrapError, "capture description")[1], CAPTURE_SCHEMA, str(path),
                       UnwrapError)


#: Lossless image formats a scanner's own layout may use (SLStudio and SLMaster write BMP).
FRAME_SUFFIXES = (".png", ".bmp", ".tif", ".tiff")


def frame_file(folder: Path, stem: str) -> Path:
    """``folder/stem`` with the first suffix of :data:`FRAME_SUFFIXES` that exists (``.png`` when
    none does, so that a missing frame is reported by its usual name)."""
    for suffix in FRAME_SUFFIXES:
        if (folder / f"{stem}{suffix}").exists():
            return folder / f"{stem}{suffix}"
    return folder / f"{stem}.png"


def detect_preset(folder: Path) -> str:
    if (folder / "capture.toml").exists():
        meta = read_toml(folder / "capture.toml")
        return meta.get("capture", {}).get("preset", "design")
    if (folder / "config.xml").exists() and (folder / "pat00.png").exists():
        return "kamino-phaseshift"
    if frame_file(folder, "graycode_00").exists():
        return "procam-graycode"
    if frame_file(folder / "L", "0").exists() or frame_file(folder, "0").exists():
        return "slmaster"
    if frame_file(folder, "frameSeq_00").exists():
        return "slstudio"
    raise UnwrapError(f"{folder}: no capture.toml and not a known scanner layout "
                      f"(presets: {', '.join(PRESETS)})")


def load_capture(folder, preset: str | None = None, pose: str | None = None, *,
                 description: dict | None = None) -> Capture:
    """Describe the capture in ``folder`` (no pixels read yet). See the module docstring.

    ``description``: the session's capture.toml as a dict, already read (a session's poses do
    not read it again), or for layouts whose frames do not say everything (``procam-graycode``:
    the projector size); default: ``capture.toml`` in the folder or, for a pose folder, in its
    parent."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"capture folder not found: {folder}")
    preset = preset or detect_preset(folder)
    preset = PRESET_ALIASES.get(preset, preset)
    if preset not in PRESETS:
        raise UnwrapError(f"unknown capture preset {preset!r}: expected one of {PRESETS}")
    if preset == "procam-graycode":
        return _procam(folder, description)
    if preset == "design":
        return _design(folder, pose, description)
    return {"slstudio": _slstudio, "slmaster": _slmaster, "kamino-phaseshift": _kamino}[preset](folder, pose)


def design_frame_stem(orientation: str, frequency: float, step: int) -> str:
    """File name (without extension) of a DESIGN.md frame, e.g. ``v_f048_n05``."""
    return f"{orientation}_f{int(round(frequency)):03d}_n{step:02d}"


def read_design_pattern(toml, meta: dict | None = None) -> tuple:
    """``[pattern]`` and ``[projector]`` of a DESIGN.md ``capture.toml`` (``meta``: its contents
    when already read): (frequencies (list of float), steps (list of int, one per frequency),
    projector size (W, H)). UnwrapError names a missing or inconsistent key."""
    toml = Path(toml)
    if meta is None:
        if not toml.exists():
            raise FileNotFoundError(f"{toml.parent}: capture.toml missing (DESIGN.md layout)")
        meta = read_toml(toml)
    kind = meta.get("pattern", {}).get("kind", "phase-shift")
    if kind == GRAY_KIND:
        raise UnwrapError(f"{toml}: [pattern] kind = \"graycode\": a Gray-code-only session has no phase-shift "
                          "frequencies; decode it with method 'gray'")
    if kind != "phase-shift":
        raise UnwrapError(f"{toml}: [pattern] kind = {kind!r}: expected \"phase-shift\" (steps, frequencies; "
                          f"the default) or \"{GRAY_KIND}\" (Gray code only: block_px, inverse)")
    if "frequencies" not in meta.get("pattern", {}):
        raise UnwrapError(f"{toml}: [pattern] has no 'frequencies': a phase-shift session lists its fringe "
                          f"frequencies (and steps); a session of Gray code only says kind = \"{GRAY_KIND}\" "
                          "(docs/unwrap.md, Gray-code sessions)")
    if not meta["pattern"]["frequencies"]:
        raise UnwrapError(f"{toml}: [pattern] frequencies = []: a phase-shift session needs at least one "
                          f"frequency; a session of Gray code only says kind = \"{GRAY_KIND}\"")
    try:
        freqs = [float(v) for v in meta["pattern"]["frequencies"]]
        steps = meta["pattern"]["steps"]
        W, H = (int(v) for v in meta["projector"]["size"])
        steps = [int(steps)] * len(freqs) if isinstance(steps, int) else [int(s) for s in steps]
    except KeyError as exc:
        raise UnwrapError(f"{toml}: missing key {exc} ([pattern] frequencies, steps; "
                          "[projector] size)") from None
    except (TypeError, ValueError) as exc:
        raise UnwrapError(f"{toml}: [pattern] frequencies / steps and [projector] size must be numbers "
                          f"({exc})") from None
    if not freqs or not all(math.isfinite(f) and f > 0 for f in freqs) or W <= 0 or H <= 0:
        raise UnwrapError(f"{toml}: frequencies must be > 0 and the projector size positive, got "
                          f"frequencies {freqs}, size [{W}, {H}]")
    if len(steps) != len(freqs):
        raise UnwrapError(f"{toml}: {len(steps)} step counts for {len(freqs)} frequencies")
    if any(n < 3 for n in steps):
        raise UnwrapError(f"{toml}: [pattern] steps must be >= 3 each, got {steps}")
    design_shifts(meta["pattern"], toml, steps)   # refuse bad shift keys with the rest of [pattern]
    return freqs, steps, (W, H)


def design_shifts(pattern: dict, source, steps) -> list:
    """Decoding shifts (rad), one (N_i,) array per frequency, from a ``capture.toml`` ``[pattern]``.

    The frames are ``I_n = A + B cos(Phi + phase_offset - delta_n)`` with ``delta_n = shifts[i][n]``
    when ``shifts`` is given (one list per frequency, or one list for every frequency), else
    ``shift_sign * 2 pi n / N`` (``shift_sign`` 1, DESIGN.md's convention, or -1 for captures
    written as ``A + B cos(Phi + 2 pi n/N)``); ``phase_offset`` defaults to 0. The decoder uses
    ``delta_n - phase_offset``, so the phase it returns is ``Phi``. UnwrapError names a bad key.

    >>> [np.round(d, 4).tolist() for d in design_shifts({"shift_sign": -1, "phase_offset": math.pi}, "t", [4])]
    [[-3.1416, -4.7124, -6.2832, -7.854]]
    """
    sign = pattern.get("shift_sign", 1)
    if isinstance(sign, bool) or sign not in (1, -1):
        raise UnwrapError(f"{source}: [pattern] shift_sign must be 1 (A + B cos(Phi - 2 pi n/N), DESIGN.md) "
                          f"or -1 (A + B cos(Phi + 2 pi n/N)), got {sign!r}")
    offset = pattern.get("phase_offset", 0.0)
    if isinstance(offset, bool) or not isinstance(offset, (int, float)) or not math.isfinite(offset):
        raise UnwrapError(f"{source}: [pattern] phase_offset must be a finite number (rad), got {offset!r}")
    if "shifts" not in pattern:
        return [sign * 2 * math.pi * np.arange(n) / n - offset for n in steps]
    given = pattern["shifts"]
    if isinstance(given, list) and given and not isinstance(given[0], list):
        given = [given] * len(steps)
    if not isinstance(given, list) or len(given) != len(steps):
        raise UnwrapError(f"{source}: [pattern] shifts must be one list of shifts (rad) per frequency "
                          f"({len(steps)}), or one list for all, got {pattern['shifts']!r}")
    out = []
    for i, (row, n) in enumerate(zip(given, steps)):
        if (not isinstance(row, list) or len(row) != n
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in row)):
            raise UnwrapError(f"{source}: [pattern] shifts[{i}] must hold {n} finite numbers (rad, one per step), "
                              f"got {row!r}")
        out.append(np.asarray(row, dtype=np.float64) - offset)
    return out


def _check_no_extra_frames(cap: Capture, frames_dir: Path, steps) -> None:
    """Refuse frames named like the layout's that the description does not account for: a frame
    ``v_f048_n12.png`` beside ``steps = 12`` means the step count is wrong, and decoding would
    silently use the wrong shifts."""
    expected = {Path(f).stem for oc in cap.orientations.values() for s in oc.sets for f in s.files}
    extra = sorted(p.name for p in frames_dir.glob("[vh]_f*_n*.*") if p.stem not in expected)
    if extra:
        raise UnwrapError(f"{frames_dir}: frame(s) {extra[:4]}{' ...' if len(extra) > 4 else ''} are not "
                          f"described by capture.toml's [pattern] (steps = {list(steps)}): wrong step count "
                          "or frequencies?")


def check_design_description(toml, meta: dict | None = None) -> dict:
    """Validate a DESIGN.md ``capture.toml`` of either kind (phase shift: :func:`read_design_pattern`;
    Gray code only: :func:`unwrap.graycode_capture.read_gray_pattern`); returns it as a dict
    (``meta``: its contents when already read)."""
    toml = Path(toml)
    if meta is None:
        if not toml.exists():
            raise FileNotFoundError(f"{toml.parent}: capture.toml missing (DESIGN.md layout)")
        meta = read_toml(toml)
    if meta.get("pattern", {}).get("kind") == GRAY_KIND:
        read_gray_pattern(meta, toml)
    else:
        read_design_pattern(toml, meta)
    return meta


def _frames_dir(folder: Path, pose, frame_glob: str) -> Path:
    if pose is not None:
        return folder / pose
    if list(folder.glob(frame_glob)):
        return folder
    poses = sorted(p for p in folder.iterdir() if p.is_dir() and p.name.startswith("pose_"))
    if not poses:
        raise UnwrapError(f"{folder}: no frames {frame_glob} and no pose_* folders")
    return poses[0]


def _gray_capture(folder: Path, preset: str, orientations: dict) -> Capture:
    cap = Capture(folder, preset, default_method="gray")
    for o, spec in orientations.items():
        cap.orientations[o] = OrientationCapture(o, spec["width"], [], gray=spec["gray"], white=spec["white"],
                                                 black=spec["black"])
    return cap


def _procam(folder: Path, description) -> Capture:
    if description is None:
        for toml in (folder / "capture.toml", folder.parent / "capture.toml"):
            if toml.exists():
                description, source = read_toml(toml), toml
                break
        else:
            raise UnwrapError(f"{folder}: procam-graycode frames do not say how many bits are columns: give the "
                              "projector size in a capture.toml ([projector] size; in the folder, its parent, "
                              "or --capture-toml)")
    else:
        source = f"{folder} (capture description)"
    cap = _gray_capture(folder, "procam-graycode", procam_orientations(folder, read_gray_pattern(description, source)))
    cap.camera_size = camera_size(description, source)
    return cap


def _design(folder: Path, pose, description: dict | None = None) -> Capture:
    toml = folder / "capture.toml"
    meta = check_design_description(toml, description)
    if meta.get("pattern", {}).get("kind") == GRAY_KIND:
        frames_dir = _frames_dir(folder, pose, "[vh]_gray_b*.*")
        stray = sorted(p.name for p in frames_dir.glob("[vh]_f*_n*.*"))
        if stray:
            raise UnwrapError(f"{frames_dir}: phase-shift frame(s) {stray[:4]}{' ...' if len(stray) > 4 else ''} beside "
                              f"[pattern] kind = \"{GRAY_KIND}\", which decodes Gray code only: wrong kind?")
        cap = _gray_capture(folder, "design", design_gray_orientations(frames_dir, read_gray_pattern(meta, toml)))
        cap.camera_size = camera_size(meta, toml)
        return cap
    freqs, steps, (W, H) = read_design_pattern(toml, meta)
    shifts = design_shifts(meta.get("pattern", {}), toml, steps)
    frames_dir = _frames_dir(folder, pose, "[vh]_f*_n*.*")
    cap = Capture(folder, "design", default_method=meta.get("capture", {}).get("method", "mf"),
                  camera_size=camera_size(meta, toml))
    for o, width in (("v", W), ("h", H)):
        sets = []
        for f, n, delta in zip(freqs, steps, shifts):
            files, missing = [], []
            for j in range(n):
                stem = design_frame_stem(o, f, j)
                hits = sorted(frames_dir.glob(f"{stem}.*"))
                if hits:
                    files.append(hits[0])
                else:
                    missing.append(stem)
            if len(files) == 0:
                break
            if missing:
                raise UnwrapError(f"{frames_dir}: orientation {o}, frequency {f:g}: found {len(files)} "
                                  f"of {n} frames {o}_f{int(round(f)):03d}_nNN; missing {missing}")
            sets.append(FringeSet(f, files, delta))
        if sets:
            if len(sets) != len(freqs):
                raise UnwrapError(f"{frames_dir}: orientation {o} has {len(sets)} of {len(freqs)} frequencies")
            white = frames_dir / "white.png"
            cap.orientations[o] = OrientationCapture(o, float(width), sets,
                                                     white=white if white.exists() else None)
    if not cap.orientations:
        raise UnwrapError(f"{frames_dir}: no frames named like v_f{int(freqs[0]):03d}_n00.png")
    _check_no_extra_frames(cap, frames_dir, steps)
    return cap


def camera_size(meta: dict, source) -> tuple | None:
    """``[camera] size`` (W, H) of a ``capture.toml`` (None when absent); UnwrapError if malformed."""
    size = meta.get("camera", {}).get("size")
    if size is None:
        return None
    if (not isinstance(size, list) or len(size) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)):
        raise UnwrapError(f"{source}: [camera] size must be [width, height] in pixels, got {size!r}")
    return (size[0], size[1])


def _slstudio(folder: Path, pose) -> Capture:
    files = [frame_file(folder, f"frameSeq_{i:02d}") for i in range(12)]
    n = sum(f.exists() for f in files)
    if n not in (6, 12):
        raise UnwrapError(f"{folder}: slstudio layout needs frameSeq_00..05 or 00..11, found {n} frames")
    shifts = 2 * math.pi * np.arange(3) / 3
    cap = Capture(folder, "slstudio", default_method="mf")
    for o, width, first in (("v", 1824.0, 0), ("h", 1140.0, 6))[: n // 6]:
        cap.orientations[o] = OrientationCapture(o, width, [
            FringeSet(1.0, files[first + 3:first + 6], shifts),
            FringeSet(16.0, files[first:first + 3], shifts)])
    return cap


def _slmaster(folder: Path, pose) -> Capture:
    d = folder / "L" if (folder / "L").is_dir() else folder
    files = [frame_file(d, str(i)) for i in range(18)]
    missing = [f.name for f in files if not f.exists()]
    if missing:
        raise UnwrapError(f"{d}: slmaster layout needs 0.png .. 17.png (or .bmp); missing {missing}")
    shifts = math.pi - 2 * math.pi * np.arange(12) / 12
    cap = Capture(folder, "slmaster", default_method="gray")
    cap.orientations["v"] = OrientationCapture(
        "v", 1920.0, [FringeSet(32.0, files[:12], shifts)],
        gray={"kind": "complementary", "files": files[12:18], "n_bits": 5})
    return cap


def _read_config_xml(path: Path) -> dict:
    text = path.read_text()
    out = {}
    for key in ("disp_width", "disp_height", "step"):
        m = re.search(rf"<{key}>\s*([0-9.]+)\s*</{key}>", text)
        if not m:
            raise UnwrapError(f"{path}: <{key}> missing")
        out[key] = float(m.group(1))
    return out


def _kamino(folder: Path, pose) -> Capture:
    cfg = _read_config_xml(folder / "config.xml")
    W, H, step = cfg["disp_width"], cfg["disp_height"], cfg["step"]
    block = step / 2
    files = [folder / f"pat{i:02d}.png" for i in range(64) if (folder / f"pat{i:02d}.png").exists()]
    n_col = math.ceil(math.log2(int((W - 1) // block) + 1))
    n_row = math.ceil(math.log2(int((H - 1) // block) + 1))
    expected = 12 + 2 * (n_col + n_row) + 2
    if len(files) != expected:
        raise UnwrapError(f"{folder}: kamino layout with {W:g}x{H:g}, step {step:g} needs {expected} "
                          f"frames pat00..; found {len(files)}")
    shifts = np.array([2 * math.pi / 3, 0.0, -2 * math.pi / 3])  # cos(x w + (phs-2) 2pi/3), phs=1..3
    gray = files[12:12 + 2 * (n_col + n_row)]
    cap = Capture(folder, "kamino-phaseshift", default_method="gray")
    for o, width, first, bits in (("v", W, 0, gray[:2 * n_col]), ("h", H, 6, gray[2 * n_col:])):
        cap.orientations[o] = OrientationCapture(
            o, width,
            [FringeSet(width / (step / 2), files[first + 3:first + 6], shifts),   # period step/2
             FringeSet(width / (step / 3), files[first:first + 3], shifts)],      # period step/3
            gray={"kind": "opencv", "files": bits[0::2], "inverse": bits[1::2], "block_px": block},
            white=files[-2], black=files[-1])
    return cap
