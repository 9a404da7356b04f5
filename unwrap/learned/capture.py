"""Unwrap a capture folder with a trained model (``calib unwrap CAPTURE --model learned``).

Per orientation: the N-step wrapped phase of the pair the model takes (MF: the lowest, unit
frequency and the highest; MW / NT: the two highest, one period apart), the traditional prior and
order, then :func:`unwrap.learned.infer.unwrap_learned`. The result is an
:class:`unwrap.pipeline.OrientationResult` like the traditional path's (so ``write_results``
writes the same ``unwrap.h5``), with ``order`` / ``phase`` from the network and two more maps:
``confidence`` (probability of the chosen correction, 0 where invalid) and ``order_traditional``.
Intermediate frequencies of a longer MF ladder are not used: the model was trained on the pair.

The traditional path's checks hold here too: every frame goes through one
:class:`unwrap.capture.FrameReader` (mixed bit depth or size refused, naming the frame), the
traditional prior of the pair must cluster near integers (:mod:`unwrap.consistency`; wrong
ladder or phase-shift convention, ``check_prior=False`` decodes anyway), and an absolute phase
outside the pattern is invalid (:func:`unwrap.temporal.constrain_to_pattern`).
"""
from __future__ import annotations

import logging
import math

import numpy as np

from .._xp import TWO_PI
from ..capture import FrameReader, load_capture
from ..consistency import check_priors, prior_check
from ..methods import pair_indices
from ..phase_shift import wrapped_phase
from ..pipeline import OrientationResult, check_min_modulation, each_orientation
from ..temporal import Unwrapped, constrain_to_pattern
from .beat_window import wrap_orders
from .errors import ModelError
from .infer import unwrap_learned
from .runtime import load_predictor

log = logging.getLogger("unwrap.learned")


def learned_orientation(oc, method: str, model, *, min_modulation=None, on_outside: str = "raise",
                        check_prior: bool = True, camera_size=None, progress: bool = False,
                        then=()) -> OrientationResult:
    """One orientation of a capture (:class:`unwrap.capture.OrientationCapture`) by the network
    (checks: module docstring; ``camera_size`` (W, H) the frames must have; ``then``: frame files to
    start decoding once the forward is done, :func:`unwrap.capture.prefetch`)."""
    reader = FrameReader(camera_size)
    sets = sorted(oc.sets, key=lambda s: s.frequency)
    freqs = [float(s.frequency) for s in sets]
    i_lo, i_hi = pair_indices(method, len(freqs), ModelError)
    w = {}
    for i in (i_lo, i_hi):
        stack = reader.phase_stack(sets[i].files)
        mm = check_min_modulation(min_modulation, stack.dtype)
        full = float(np.iinfo(stack.dtype).max) if np.issubdtype(stack.dtype, np.integer) else 1.0
        ph = wrapped_phase(stack, sets[i].shifts, min_modulation=mm)
        del stack
        # only what is used below: ``A`` is a view of the (3, H, W) fit coefficients, so the
        # high frequency's is copied out (the other two planes are freed) and the low one's dropped
        w[i] = (ph.phase, ph.valid, ph.B, ph.A.copy() if i == i_hi else None, full)
        del ph
        used_mm = mm
        log.log(logging.INFO if progress else logging.DEBUG, "  [%s] f = %g: %d frames", oc.orientation,
                freqs[i], len(sets[i].files))
    (lo_phase, lo_valid, lo_B, _, full_lo), (hi_phase, hi_valid, hi_B, hi_A, full_hi) = w.pop(i_lo), w.pop(i_hi)
    valid = lo_valid & hi_valid
    r = unwrap_learned(method, lo_phase, hi_phase, lo_B / full_lo, hi_B / full_hi, valid, (freqs[i_lo], freqs[i_hi]),
                       width=oc.width, model=model, on_outside=on_outside)
    if then:
        from ..capture import prefetch

        prefetch(then)
    del lo_phase, lo_B, lo_valid
    ok = r.order >= 0
    phase = np.where(ok, np.nan_to_num(hi_phase) + TWO_PI * r.order, math.nan)
    # the traditional decode's range constraint: MW / NT move a phase by one period of the beat
    phase, order, ok = constrain_to_pattern(np, phase, r.order, ok, freqs[i_hi], oc.width,
                                            wrap_orders(method, freqs[i_lo], freqs[i_hi]))
    phase = np.where(ok, phase, math.nan)
    res = Unwrapped(phase, np.where(ok, order, -1).astype(np.int32), ok, np.where(r.valid, r.prior, math.nan),
                    freqs[i_hi], f"{method}+learned")
    checks = prior_check(Unwrapped(phase, order, r.valid, r.prior, freqs[i_hi], method))
    if check_prior:
        check_priors(checks, f"orientation {oc.orientation}, method {method} (learned; the traditional prior)")
    if not ok.any():
        raise ModelError(f"orientation {oc.orientation}: no valid pixel (modulation threshold {used_mm:.3g}; "
                         "all-black frames, or a threshold above what the frames hold?)")
    extras = {"confidence": r.confidence.astype(np.float32), "order_traditional": r.order_traditional.astype(np.int32)}
    log.log(logging.INFO if progress else logging.DEBUG, "  [%s] learned: %d of %d valid pixels changed from the "
            "traditional order; frequency check %s", oc.orientation, int((r.order != r.order_traditional)[ok].sum()),
            int(ok.sum()), r.frequency_check.get("status"))
    return OrientationResult(oc.orientation, oc.width, res, hi_B, hi_A, min_modulation=used_mm, prior_check=checks,
                             extras=extras)


def pair_files(oc, method: str) -> list:
    """The frame files :func:`learned_orientation` reads from orientation ``oc``, in its order (the
    low, then the high frequency of the pair; ``[]`` where the capture holds no such pair)."""
    sets = sorted(oc.sets, key=lambda s: s.frequency)
    try:
        i_lo, i_hi = pair_indices(method, len(sets), ModelError)
    except ModelError:
        return []
    return [f for i in (i_lo, i_hi) for f in sets[i].files]


def unwrap_capture_learned(folder, method: str = "mf", model="learned", *, preset=None, pose=None,
                           min_modulation=None, on_outside: str = "raise", check_prior: bool = True,
                           progress: bool = False) -> dict:
    """Every orientation of a capture folder by the network: {"v": OrientationResult, ...}.

    Frames are decoded ahead on the package's pool (:func:`unwrap.capture.prefetch`): an
    orientation's pair as it starts (the high frequency's frames decode while the low one's phase
    is fitted), the next orientation's once this one's forward is done (while its decode, checks
    and result are made), so that no decoded frame waits through a forward, the command's peak;
    what an error leaves unread is dropped."""
    from ..capture import forget_prefetched, prefetch

    cap = load_capture(folder, preset, pose)
    net = load_predictor(model)          # loaded once (cached per process), shared by the orientations
    # (the features' plane fits run in C, else numpy, unless the process warmed numba's kernel up: a batch)
    files = {o: pair_files(oc, method) for o, oc in cap.orientations.items()}
    after = dict(zip(files, [*list(files.values())[1:], []]))

    def one(oc):
        prefetch(files[oc.orientation])
        return learned_orientation(oc, method, net, min_modulation=min_modulation, on_outside=on_outside,
                                   check_prior=check_prior, camera_size=cap.camera_size, progress=progress,
                                   then=after[oc.orientation])
    try:
        return each_orientation(cap, f"{method} + learned", one, progress)
    finally:
        forget_prefetched([f for fs in files.values() for f in fs])
