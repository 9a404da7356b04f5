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
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import warmup
from ._xp import wrap
from .capture import Capture, FrameReader, OrientationCapture, forget_prefetched, load_capture, prefetch
from .consistency import check_priors, prior_check
from .errors import UnwrapError
from .fused_mf import mf_unwrap_stacks, native_kernel
from .graycode import binarize, complementary_gray_unwrap, gray_coarse_unwrap, gray_code_unwrap, gray_to_index
from .methods import METHODS, PAIR_METHODS
from .patterns import projector_coordinate
from .phase_io import write_phase_file
from .phase_shift import wrapped_phase
from .reliability import fit_noise_sigma, modulation_threshold, predicted_error_rate
from .temporal import Unwrapped, mf_unwrap, mw_unwrap, nt_unwrap


log = logging.getLogger(__name__)


@dataclass
class OrientationResult:
    """One orientation decoded: ``result`` (the :class:`Unwrapped`: absolute phase, order, valid),
    the pattern ``width`` (px), ``modulation`` (B of the highest frequency; Gray code only:
    white - black) and ``background`` (A; Gray code only: (white + black) / 2), both (H, W) in
    input units, and what the decode assumed and predicts:

    - ``min_modulation``: the modulation threshold used (input units);
    - ``noise_sigma``: intensity noise per frame (from the fit residuals, or given; None when
      neither: 3-step frames carry no residual, Gray code has no fit);
    - ``predicted_error_rate``: upper bound of the predicted fraction of wrong fringe orders among
      the kept pixels (:func:`unwrap.reliability.predicted_error_rate`; None without a noise
      level or a reliability model for the method);
    - ``prior_check``: (frequency, fraction of kept pixels whose prior lies within 1/4 of an
      integer) per rounding step (:mod:`unwrap.consistency`);
    - ``quantisation_px``: None, or the block size when the projector coordinate is a Gray block
      centre (no phase shifting).
    """
    orientation: str
    width: float
    result: Unwrapped
    modulation: np.ndarray
    background: np.ndarray
    min_modulation: float = 0.0
    noise_sigma: float | None = None
    predicted_error_rate: float | None = None
    prior_check: list = field(default_factory=list)
    quantisation_px: float | None = None
    extras: dict = field(default_factory=dict)   # more per-pixel maps for unwrap.h5 (e.g. confidence)


def _default_min_modulation(dtype) -> float:
    if np.issubdtype(dtype, np.integer):
        return 0.02 * float(np.iinfo(dtype).max)
    return 0.0


def check_min_modulation(value, dtype) -> float:
    """The modulation threshold (input units): 2 % of full scale by default (integer frames);
    refused when negative, not finite, or above the largest modulation the frames can hold
    (half the full scale of integer frames)."""
    if value is None:
        return _default_min_modulation(dtype)
    value = float(value)
    if not (math.isfinite(value) and value >= 0):
        raise UnwrapError(f"min_modulation must be a finite number >= 0 (grey levels), got {value:g}")
    if np.issubdtype(dtype, np.integer) and value > 0.5 * np.iinfo(dtype).max:
        raise UnwrapError(f"min_modulation {value:g} exceeds the largest modulation {np.dtype(dtype).name} frames "
                          f"can hold ({0.5 * np.iinfo(dtype).max:g} = half the full scale): no pixel could pass")
    return value


def _kernel_cold() -> bool:
    """True when the fused kernel is neither compiled in this process nor cached on disk (numba's;
    the C replica, where it loads, is never cold: its one compile, 1-2 s, is not worth a line)."""
    from .fused_mf import fast_available, native_kernel
    if native_kernel() is not None or not fast_available():
        return False
    from . import _fused_kernel
    if _fused_kernel.mf_kernel.signatures:
        return False
    try:   # numba's on-disk cache (cache=True): an index file per compiled function
        return not Path(_fused_kernel.mf_kernel._cache._cache_file._index_path).exists()
    except (AttributeError, TypeError, OSError):
        return True


def _log(progress, msg):
    """Progress to the ``unwrap`` logger: INFO when ``progress`` is asked for, else DEBUG."""
    log.log(logging.INFO if progress else logging.DEBUG, msg)


def read_orientation(oc: OrientationCapture, reader: FrameReader, progress: bool = False) -> list:
    """The phase-shift stacks of one orientation, lowest frequency first (every frame read, each
    checked by ``reader``: :class:`unwrap.capture.FrameReader` refuses mixed bit depth or size and
    frames whose size contradicts the description's camera size)."""
    sets = sorted(oc.sets, key=lambda s: s.frequency)
    stacks = []
    for i, s in enumerate(sets):
        _log(progress, f"  [{oc.orientation}] {i + 1}/{len(sets)}: f = {s.frequency:g}, {len(s.files)} frames")
        stacks.append(reader.phase_stack(s.files))
    return stacks


def _reliability_model(oc: OrientationCapture, method: str):
    """The reliability model's method name for ``method`` on this capture, or None."""
    if method in PAIR_METHODS:
        return method
    if method == "gray" and oc.gray is not None and oc.gray.get("kind") == "complementary":
        return "cgray"
    return None


def _noise_sigma(stacks, sets, noise_sigma):
    """The given noise level, else the fit residuals' estimate of the highest frequency (N >= 4), else None."""
    if noise_sigma is not None:
        if not (math.isfinite(noise_sigma) and noise_sigma > 0):
            raise UnwrapError(f"noise_sigma must be finite and > 0 (grey levels), got {noise_sigma!r}")
        return float(noise_sigma)
    top, shifts = stacks[-1], sets[-1].shifts
    if top.shape[0] < 4:
        return None
    w = wrapped_phase(top, shifts, min_modulation=_default_min_modulation(top.dtype))
    return fit_noise_sigma(top, shifts, w.valid) if w.valid.any() else None


def unwrap_orientation(oc: OrientationCapture, method: str, *, min_modulation=None, max_error_rate=None,
                       noise_sigma=None, check_prior: bool = True, camera_size=None,
                       gray_min_contrast: float = 4.0, progress: bool = False, then=()) -> OrientationResult:
    """Wrapped phases of every fringe set, then the chosen temporal method, for one orientation.

    ARGUMENTS
    - oc: the orientation's frames (:mod:`unwrap.capture`); method: "mf", "mw", "nt", "gray".
    - min_modulation: modulation threshold B (input units; default 2 % of full scale), or
    - max_error_rate: the threshold from the reliability model instead: the smallest B at which
      the method's predicted fringe-order error rate (with this capture's step counts and noise)
      is at most this (:func:`unwrap.reliability.modulation_threshold`).
    - noise_sigma: intensity noise per frame (input units; default: estimated from the fit
      residuals of the highest frequency, which needs N >= 4).
    - check_prior: refuse a decode whose priors are not clustered near integers
      (:func:`unwrap.consistency.check_priors`: wrong ladder or phase-shift convention).
    - camera_size: (W, H) the frames must have.
    - then: frames to start decoding (:func:`unwrap.capture.prefetch`) once this orientation's
      phase-shift frames are read: the next orientation's, decoded while this one is.
    An orientation of Gray code only (no fringe sets) decodes with method "gray" alone (block
    centres, ``quantisation_px``; no reliability model, so no ``max_error_rate``).
    Refused (UnwrapError): mixed bit depth or size, no valid pixel, inconsistent priors.
    """
    if method not in METHODS:
        raise UnwrapError(f"unknown method {method!r}: expected one of {METHODS}")
    if max_error_rate is not None and min_modulation is not None:
        raise UnwrapError("give min_modulation or max_error_rate, not both")
    reader = FrameReader(camera_size)
    if not oc.sets:
        if method != "gray":
            raise UnwrapError(f"orientation {oc.orientation}: this capture holds Gray code only (no phase-shift "
                              f"frames), which method {method!r} cannot decode; use method 'gray'")
        if max_error_rate is not None:
            raise UnwrapError("max_error_rate: no reliability model for Gray code without phase shifting "
                              "(a bit is right or wrong, not noisy in phase); give min_modulation")
        out = _gray_only(oc, reader, min_modulation, gray_min_contrast, progress)
        _check_some_valid(out, out.min_modulation)
        return out
    sets = sorted(oc.sets, key=lambda s: s.frequency)
    warm = (warmup.fused_mf_for(sets[0].files[0], len(sets), max(len(s.files) for s in sets))
            if method == "mf" and len(sets) >= 2 and native_kernel() is None
            else None)   # numba's kernel loads while the frames are read (the C replica needs no warm-up)
    stacks = read_orientation(oc, reader, progress)
    prefetch(then)
    model = _reliability_model(oc, method)
    if noise_sigma is None and max_error_rate is None:   # not needed before the decode: estimated beside it
        from ._threads import pool
        sigma_job = pool("noise").submit(_noise_sigma, stacks, sets, None)
        sigma = None
    else:
        sigma_job, sigma = None, _noise_sigma(stacks, sets, noise_sigma)
    if max_error_rate is not None:
        if model is None:
            raise UnwrapError(f"max_error_rate: no reliability model for method {method!r} on this capture "
                              "(models: mf, mw, nt, complementary Gray code); give min_modulation")
        if sigma is None:
            raise UnwrapError(f"max_error_rate: the noise level cannot be estimated from {stacks[-1].shape[0]} "
                              "frames (needs >= 4 per frequency); give noise_sigma (--noise-sigma)")
        mm = modulation_threshold(model, [s.frequency for s in sets], [len(s.files) for s in sets], sigma,
                                  max_error_rate)
        check_min_modulation(mm, stacks[0].dtype)
        _log(progress, f"  [{oc.orientation}] noise {sigma:.3g} per frame -> modulation threshold {mm:.3g} for "
                       f"a predicted error rate <= {max_error_rate:g} ({model})")
    else:
        mm = check_min_modulation(min_modulation, stacks[0].dtype)
    out = _decode(oc, sets, stacks, reader, method, mm, gray_min_contrast, progress, warm)
    _check_some_valid(out, mm)
    if sigma_job is not None:
        sigma = sigma_job.result()
    out.min_modulation, out.noise_sigma = mm, sigma
    out.prior_check = prior_check(out.result) if method != "gray" else []
    if check_prior:
        check_priors(out.prior_check, f"orientation {oc.orientation}, method {method}")
    if sigma is not None and model is not None:
        out.predicted_error_rate = predicted_error_rate(
            model, [s.frequency for s in sets], [len(s.files) for s in sets], sigma,
            np.asarray(out.modulation)[np.asarray(out.result.valid)])
    return out


def _check_some_valid(out: OrientationResult, mm: float) -> None:
    if np.any(out.result.valid):
        return
    B = np.asarray(out.modulation)
    raise UnwrapError(f"orientation {out.orientation}: no valid pixel (modulation threshold {mm:g}, the largest "
                      f"modulation in the frames is {float(np.max(B)) if B.size else 0:g}): all-black or "
                      "saturated frames, or too high a threshold")


def _decode(oc, sets, stacks, reader, method, mm, gray_min_contrast, progress, warm=None) -> OrientationResult:
    freqs = [s.frequency for s in sets]
    if method == "mf" and len(sets) >= 2:
        # one fused pass (unwrap.fused_mf) for 8/16-bit frames, the reference otherwise
        if progress and _kernel_cold():
            _log(progress, f"  [{oc.orientation}] wrapped phase + MF: first use of the fused kernel on this "
                           "machine (compiled once and cached, ~15 s)")
        if warm is not None:
            warm.wait()
        r = mf_unwrap_stacks(stacks, freqs, shifts=[s.shifts for s in sets], width=oc.width,
                             min_modulation=mm, levels=True)
        return OrientationResult(oc.orientation, oc.width, r.result, r.modulation, r.background)
    phases, valid, last = [], None, None
    for s, stack in zip(sets, stacks):
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
        res = _gray(oc, reader, phases, freqs, valid, last, gray_min_contrast, progress)
    return OrientationResult(oc.orientation, oc.width, res, last.B, last.A)


def _gray_only(oc, reader, min_modulation, min_contrast, progress) -> OrientationResult:
    """Gray code without phase shifting: block index -> block centre (``gray_code_unwrap``); valid
    where every bit clears ``min_contrast`` against its inverse (or against (white + black) / 2)
    and white - black clears ``min_modulation`` (default 2 % of full scale; checked as for phase
    shifting). Every frame goes through ``reader`` (bit depth, size, camera size)."""
    g = oc.gray
    _log(progress, f"  [{oc.orientation}] Gray code only: {len(g['files'])} bits"
                   f"{' with inverses' if g.get('inverse') else ''}, blocks of {g['block_px']} px")
    frames = reader.stack(g["files"])
    white = black = None
    if oc.white is not None and oc.black is not None:
        white, black = (reader.image(f).astype(np.float64) for f in (oc.white, oc.black))
    if g.get("inverse"):
        inverse = reader.stack(g["inverse"])
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
    mm = check_min_modulation(min_modulation, frames.dtype)
    res = gray_code_unwrap(gray_to_index(bits), g["block_px"], oc.width, reliable=reliable, valid=contrast > mm)
    return OrientationResult(oc.orientation, oc.width, res, contrast, background, mm,
                             quantisation_px=float(g["block_px"]))


def _gray(oc, reader, phases, freqs, valid, last, min_contrast, progress) -> Unwrapped:
    if oc.gray is None:
        raise UnwrapError(f"orientation {oc.orientation}: this capture has no Gray-code frames; its "
                          "phase-shift frames decode with method mf, mw or nt")
    g = oc.gray
    _log(progress, f"  [{oc.orientation}] Gray code: {len(g['files'])} bits ({g['kind']})")
    frames = reader.stack(g["files"])
    if g["kind"] == "complementary":
        bits, reliable = binarize(frames, threshold=last.A, min_contrast=min_contrast)
        n = g["n_bits"]
        K1 = gray_to_index(bits[:n])
        G = gray_to_index(bits[:n + 1])
        K2 = (G + 1) // 2
        return complementary_gray_unwrap(phases[-1], K1, K2, freqs[-1], reliable=reliable,
                                         valid=valid)
    inverse = reader.stack(g["inverse"])
    bits, reliable = binarize(frames, inverse, min_contrast=min_contrast)
    c = gray_to_index(bits)
    if oc.white is not None and oc.black is not None:
        reliable &= (reader.image(oc.white).astype(np.float64)
                     - reader.image(oc.black).astype(np.float64)) > min_contrast
    # beat of the two fringe frequencies (period 2 blocks) then the finer fringe
    f_lo, f_hi = freqs[0], freqs[-1]
    beat = wrap(phases[-1] - phases[0])
    return gray_coarse_unwrap(c, g["block_px"], oc.width, [beat, phases[-1]],
                              [f_hi - f_lo, f_hi], reliable=reliable, valid=valid)


def unwrap_capture(folder, method: str | None = None, *, preset: str | None = None,
                   pose: str | None = None, min_modulation=None, max_error_rate=None, noise_sigma=None,
                   check_prior: bool = True, progress: bool = False) -> dict:
    """Unwrap every orientation of a capture folder; returns {"v": OrientationResult, ...}.
    Options as :func:`unwrap_orientation`; the frames must have the description's camera size."""
    cap: Capture = load_capture(folder, preset, pose)
    method = method or cap.default_method
    ocs = list(cap.orientations.values())
    after = {oc.orientation: [f for s in sorted(nxt.sets, key=lambda s: s.frequency) for f in s.files]
             for oc, nxt in zip(ocs, ocs[1:])}     # the next orientation's frames, decoded while this one is
    try:
        return each_orientation(cap, method, lambda oc: unwrap_orientation(
            oc, method, min_modulation=min_modulation, max_error_rate=max_error_rate, noise_sigma=noise_sigma,
            check_prior=check_prior, camera_size=cap.camera_size, progress=progress,
            then=after.get(oc.orientation, ())), progress)
    finally:
        forget_prefetched([f for files in after.values() for f in files])


def each_orientation(cap: Capture, label: str, decode, progress: bool = False) -> dict:
    """The per-orientation loop of a capture: ``{"v": decode(oc), ...}`` over its
    :class:`unwrap.capture.OrientationCapture` items, one progress line each (``label``: the
    method named in it). The traditional and the learned capture paths share it."""
    out = {}
    for o, oc in cap.orientations.items():
        _log(progress, f"unwrap {cap.folder} [{cap.preset}] orientation {o}, method {label}")
        out[o] = decode(oc)
    return out


def write_results(results: dict, out_dir, *, previews: bool = True, attrs: dict | None = None,
                  previews_beside: bool = True) -> Path:
    """Write ``unwrap.h5`` (DESIGN.md layout, :mod:`unwrap.phase_io`) and PNG previews into
    ``out_dir``; returns the h5 path. ``previews_beside``: draw the previews on a thread while the
    file is compressed (written after it either way); False draws them after the file, which keeps
    their temporaries apart from the write's (the learned command's peak: docs/speed.md)."""
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
    drawn = None
    if previews and previews_beside:     # drawn and encoded on a thread while the file is compressed
        from ._threads import pool
        from .previews import encode_previews
        drawn = pool("previews").submit(encode_previews, results)
    path = write_phase_file(Path(out_dir) / "unwrap.h5", groups, attrs=attrs)
    if previews:
        _previews(results, Path(out_dir), None if drawn is None else drawn.result())
    return path


def _previews(results, out: Path, encoded=None):
    """PNG previews, drawn with OpenCV (:mod:`unwrap.previews`)."""
    from .previews import write_previews
    write_previews(results, out, encoded)
