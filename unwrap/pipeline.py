"""Capture folder -> absolute phase, fringe order and masks per orientation; HDF5 + PNG output.

SYNOPSIS (Python)

    from unwrap.pipeline import unwrap_capture, write_results
    results = unwrap_capture("captures/", method="mf")      # {"v": OrientationResult, "h": ...}
    write_results(results, "out/")                          # out/unwrap.h5, out/*_phase.png, ...

HDF5 layout (DESIGN.md): one group per orientation ``v``/``h`` with ``phase`` (float64 absolute
phase of the highest frequency, NaN invalid), ``order`` (int32, -1 invalid), ``valid`` (bool),
plus ``prior`` (float64 physics prior), ``modulation`` (float64 B of the highest frequency) and
``projector_coordinate`` (float64 px); attributes: method, frequency, width, preset, and
``quantisation_px`` for a Gray-code-only capture (the projector coordinate is a block centre).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._xp import wrap
from .capture import Capture, OrientationCapture, load_capture, read_image, read_stack
from .errors import UnwrapError
from .fused_mf import mf_unwrap_stacks
from .graycode import binarize, complementary_gray_unwrap, gray_coarse_unwrap, gray_code_unwrap, gray_to_index
from .patterns import projector_coordinate
from .phase_io import write_phase_file
from .phase_shift import wrapped_phase
from .temporal import Unwrapped, mf_unwrap, mw_unwrap, nt_unwrap

METHODS = ("mf", "mw", "nt", "gray")

log = logging.getLogger(__name__)


@dataclass
class OrientationResult:
    """One orientation decoded: ``result`` (absolute phase, order, valid), the pattern ``width``
    (px), ``modulation`` (B of the finest fringes; Gray code only: white - black) and
    ``background`` (A; Gray code only: (white + black) / 2), both (H, W) grey levels;
    ``quantisation_px``: None, or the block size when the projector coordinate is a Gray block
    centre (no phase shifting)."""
    orientation: str
    width: float
    result: Unwrapped
    modulation: np.ndarray
    background: np.ndarray
    quantisation_px: float | None = None
    extras: dict = field(default_factory=dict)   # more per-pixel maps for unwrap.h5 (e.g. confidence)


def _default_min_modulation(dtype) -> float:
    if np.issubdtype(dtype, np.integer):
        return 0.02 * float(np.iinfo(dtype).max)
    return 0.0


def _kernel_cold() -> bool:
    """True when the fused kernel has not run in this process yet (numba installed)."""
    from .fused_mf import fast_available
    if not fast_available():
        return False
    from . import _fused_kernel
    return not _fused_kernel.mf_kernel.signatures


def _log(progress, msg):
    """Progress to the ``unwrap`` logger: INFO when ``progress`` is asked for, else DEBUG."""
    log.log(logging.INFO if progress else logging.DEBUG, msg)


def unwrap_orientation(oc: OrientationCapture, method: str, *, min_modulation=None,
                       gray_min_contrast: float = 4.0, progress: bool = False) -> OrientationResult:
    """Wrapped phases of every fringe set, then the chosen temporal method, for one orientation."""
    if method not in METHODS:
        raise UnwrapError(f"unknown method {method!r}: expected one of {METHODS}")
    if not oc.sets:
        if method != "gray":
            raise UnwrapError(f"orientation {oc.orientation}: this capture holds Gray code only (no phase-shift "
                              f"frames), which method {method!r} cannot decode; use method 'gray'")
        return _gray_only(oc, min_modulation, gray_min_contrast, progress)
    sets = sorted(oc.sets, key=lambda s: s.frequency)
    freqs = [s.frequency for s in sets]
    if method == "mf" and len(sets) >= 2:
        stacks = []
        for i, s in enumerate(sets):
            _log(progress, f"  [{oc.orientation}] {i + 1}/{len(sets)}: f = {s.frequency:g}, "
                           f"{len(s.files)} frames")
            stacks.append(read_stack(s.files))
        if len({st.dtype for st in stacks}) == 1:
            # one fused pass (unwrap.fused_mf) for 8/16-bit frames, the reference otherwise
            mm = (_default_min_modulation(stacks[0].dtype) if min_modulation is None
                  else min_modulation)
            if progress and _kernel_cold():
                _log(progress, f"  [{oc.orientation}] wrapped phase + MF: first use of the fused "
                               "kernel in this process (compiles once per machine, ~15 s)")
            r = mf_unwrap_stacks(stacks, freqs, shifts=[s.shifts for s in sets], width=oc.width,
                                 min_modulation=mm)
            return OrientationResult(oc.orientation, oc.width, r.result, r.modulation, r.background)
        stacks = iter(stacks)
    else:
        stacks = None
    phases, valid, last = [], None, None
    for i, s in enumerate(sets):
        if stacks is None:
            _log(progress, f"  [{oc.orientation}] {i + 1}/{len(sets)}: f = {s.frequency:g}, "
                           f"{len(s.files)} frames")
        stack = read_stack(s.files) if stacks is None else next(stacks)
        mm = _default_min_modulation(stack.dtype) if min_modulation is None else min_modulation
        w = wrapped_phase(stack, s.shifts, min_modulation=mm)
        phases.append(w.phase)
        valid = w.valid if valid is None else valid & w.valid
        last = w
    if method == "mf":
        res = mf_unwrap(phases, freqs, width=oc.width, valid=valid)
    elif method == "mw":
        res = mw_unwrap(phases, freqs, width=oc.width, valid=valid)
    elif method == "nt":
        res = nt_unwrap(phases, freqs, width=oc.width, valid=valid)
    else:
        res = _gray(oc, phases, freqs, valid, last, gray_min_contrast, progress)
    return OrientationResult(oc.orientation, oc.width, res, last.B, last.A)


def _gray_only(oc, min_modulation, min_contrast, progress) -> OrientationResult:
    """Gray code without phase shifting: block index -> block centre (``gray_code_unwrap``); valid
    where every bit clears ``min_contrast`` against its inverse (or against (white + black) / 2)
    and white - black clears ``min_modulation`` (default 2 % of full scale)."""
    g = oc.gray
    _log(progress, f"  [{oc.orientation}] Gray code only: {len(g['files'])} bits"
                   f"{' with inverses' if g.get('inverse') else ''}, blocks of {g['block_px']} px")
    frames = read_stack(g["files"])
    white = black = None
    if oc.white is not None and oc.black is not None:
        white, black = (read_image(f).astype(np.float64) for f in (oc.white, oc.black))
        if white.shape != frames.shape[1:] or black.shape != frames.shape[1:]:
            raise UnwrapError(f"orientation {oc.orientation}: white/black frames {white.shape}, {black.shape} "
                              f"differ from the code frames {frames.shape[1:]}")
    if g.get("inverse"):
        inverse = read_stack(g["inverse"])
        bits, reliable = binarize(frames, inverse, min_contrast=min_contrast)
        mid = 0.5 * (frames.astype(np.float64) + inverse).mean(axis=0)
    elif white is not None:
        bits, reliable = binarize(frames, threshold=0.5 * (white + black), min_contrast=min_contrast)
        mid = 0.5 * (white + black)
    else:
        raise UnwrapError(f"orientation {oc.orientation}: Gray code without inverse frames needs white and black "
                          "frames to threshold against")
    if white is not None:
        contrast, background = white - black, 0.5 * (white + black)
    else:
        contrast, background = 2 * np.abs(frames.astype(np.float64) - mid).mean(axis=0), mid
    mm = _default_min_modulation(frames.dtype) if min_modulation is None else min_modulation
    res = gray_code_unwrap(gray_to_index(bits), g["block_px"], oc.width, reliable=reliable, valid=contrast > mm)
    return OrientationResult(oc.orientation, oc.width, res, contrast, background, float(g["block_px"]))


def _gray(oc, phases, freqs, valid, last, min_contrast, progress) -> Unwrapped:
    if oc.gray is None:
        raise UnwrapError(f"orientation {oc.orientation}: this capture has no Gray-code frames; its "
                          "phase-shift frames decode with method mf, mw or nt")
    g = oc.gray
    _log(progress, f"  [{oc.orientation}] Gray code: {len(g['files'])} bits ({g['kind']})")
    frames = read_stack(g["files"])
    if g["kind"] == "complementary":
        bits, reliable = binarize(frames, threshold=last.A, min_contrast=min_contrast)
        n = g["n_bits"]
        K1 = gray_to_index(bits[:n])
        G = gray_to_index(bits[:n + 1])
        K2 = (G + 1) // 2
        return complementary_gray_unwrap(phases[-1], K1, K2, freqs[-1], reliable=reliable,
                                         valid=valid)
    inverse = read_stack(g["inverse"])
    bits, reliable = binarize(frames, inverse, min_contrast=min_contrast)
    c = gray_to_index(bits)
    if oc.white is not None and oc.black is not None:
        reliable &= (read_image(oc.white).astype(np.float64)
                     - read_image(oc.black).astype(np.float64)) > min_contrast
    # beat of the two fringe frequencies (period 2 blocks) then the finer fringe
    f_lo, f_hi = freqs[0], freqs[-1]
    beat = wrap(phases[-1] - phases[0])
    return gray_coarse_unwrap(c, g["block_px"], oc.width, [beat, phases[-1]],
                              [f_hi - f_lo, f_hi], reliable=reliable, valid=valid)


def unwrap_capture(folder, method: str | None = None, *, preset: str | None = None,
                   pose: str | None = None, min_modulation=None, progress: bool = False) -> dict:
    """Unwrap every orientation of a capture folder; returns {"v": OrientationResult, ...}."""
    cap: Capture = load_capture(folder, preset, pose)
    method = method or cap.default_method
    out = {}
    for o, oc in cap.orientations.items():
        _log(progress, f"unwrap {cap.folder} [{cap.preset}] orientation {o}, method {method}")
        out[o] = unwrap_orientation(oc, method, min_modulation=min_modulation, progress=progress)
    return out


def write_results(results: dict, out_dir, *, previews: bool = True, attrs: dict | None = None) -> Path:
    """Write ``unwrap.h5`` (DESIGN.md layout, :mod:`unwrap.phase_io`) and PNG previews into
    ``out_dir``; returns the h5 path."""
    groups = {}
    for o, r in results.items():
        u = r.result
        groups[o] = {"phase": u.phase, "order": u.order, "valid": u.valid, "frequency": u.frequency,
                     "extra": {"prior": np.asarray(u.prior, dtype=np.float64),
                               "modulation": np.asarray(r.modulation, np.float64),
                               "projector_coordinate": projector_coordinate(np.asarray(u.phase), u.frequency,
                                                                            r.width),
                               **r.extras},
                     "attrs": {"method": u.method, "width": r.width, "valid_fraction": float(np.mean(u.valid)),
                               **({} if r.quantisation_px is None else {"quantisation_px": r.quantisation_px})}}
    path = write_phase_file(Path(out_dir) / "unwrap.h5", groups, attrs=attrs)
    if previews:
        _previews(results, Path(out_dir))
    return path


def _previews(results, out: Path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    for o, r in results.items():
        u = r.result
        fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
        coord = projector_coordinate(np.asarray(u.phase), u.frequency, r.width)
        for ax, img, title, cmap in (
                (axes[0], coord, f"projector coordinate ({o}) [px]", "viridis"),
                (axes[1], np.where(u.valid, u.order, np.nan), f"fringe order k (f = {u.frequency:g})", "turbo"),
                (axes[2], r.modulation, "modulation B", "gray")):
            im = ax.imshow(img, cmap=cmap)
            ax.set_title(title)
            ax.axis("off")
            fig.colorbar(im, ax=ax, fraction=0.046)
        fig.suptitle(f"{o}: method {u.method}, valid {100 * np.mean(u.valid):.1f} %")
        fig.tight_layout()
        fig.savefig(out / f"{o}_unwrap.png", dpi=80)
        plt.close(fig)
