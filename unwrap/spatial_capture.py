"""Unwrap a capture folder with the spatial graph cut (``calib unwrap CAPTURE --spatial graphcut``).

Per orientation: the N-step wrapped phases of a pair (MF: the lowest and the highest frequency;
MW / NT: the two highest, one period apart, as the learned path), the phase noise of each pixel
from the reliability model (``sqrt(2/N) sigma / B``; ``sigma`` from the fit residuals, N >= 4,
else from the high phase's residual against a local plane, or given), then
:func:`unwrap.spatial_orders.graphcut_orders` - with the prior's likelihood as data term, or with
the learned network's class log-probabilities (``model``) - and by default the never-worse gate
(:func:`unwrap.spatial_orders.gate`, thresholds :data:`unwrap.spatial_orders.GATE`). The result
is an :class:`unwrap.pipeline.OrientationResult` like the other paths' (``write_results`` writes
the same ``unwrap.h5``) with the extra maps ``order_traditional``, ``p_wrong_traditional`` (the
reliability model's error probability of the traditional order, noise only), ``p_wrong_decision``
(:func:`unwrap.decision_error.error_probability`, bias included: what the gate thresholds) and,
with a model, ``confidence``; with the global-light bound (:func:`global_bias_bound`, MF and the
prior's data term) ``global_ratio``, the global / direct ratio of :mod:`unwrap.global_light`. The
checks of the other paths hold: one :class:`unwrap.capture.FrameReader`, the traditional prior near
integers (:mod:`unwrap.consistency`), the pattern range.
"""
from __future__ import annotations

import logging
import math

import numpy as np

from ._xp import TWO_PI
from .capture import FrameReader, load_capture
from .common_window import pair_wrap_orders
from .consistency import check_priors, prior_check
from .errors import UnwrapError
from .phase_shift import wrapped_phase
from .reliability import fit_noise_sigma, plane_residual_noise
from .pipeline import OrientationResult, check_min_modulation
from .decision_error import error_probability
from .spatial_orders import DEFAULTS, GATE, MAX_CORRECTION, gate, graphcut_orders, phase_noise
from .temporal import Unwrapped, constrain_to_pattern

log = logging.getLogger("unwrap")


def _pair(method: str, freqs: list) -> tuple[int, int]:
    if len(freqs) < 2:
        raise UnwrapError(f"the spatial stage needs two fringe frequencies, the capture has {freqs}")
    if method == "mf":
        return 0, len(freqs) - 1
    if method in ("mw", "nt"):
        return len(freqs) - 2, len(freqs) - 1
    raise UnwrapError(f"method {method!r}: the spatial stage supports 'mf', 'mw' and 'nt'")


def noise_from_phase(phase_abs, valid, modulation, steps: int) -> float:
    """Intensity noise per frame (units of ``modulation``) from an absolute phase (rad, (H, W)):
    the robust spread of each interior pixel's residual against the least-squares plane of its
    5x5 neighbours, times ``B sqrt(N / 2)`` (the N-step noise gain), median over the pixels. For
    3-step captures, whose fit has no residual."""
    import torch

    from .learned.smoothing import smooth_phase

    ok = np.asarray(valid, dtype=bool) & np.isfinite(phase_abs)
    P = torch.from_numpy(np.where(ok, phase_abs, 0.0))[None, None]
    okt = torch.from_numpy(ok)[None, None]
    e = (P - smooth_phase(P, okt, 5, "plane"))[0, 0].numpy()
    interior = ok & (torch.nn.functional.avg_pool2d(okt.double(), 5, 1, 2)[0, 0].numpy() > 0.999)
    if interior.sum() < 100:
        raise UnwrapError("too few interior valid pixels to estimate the noise from the phase; give noise_sigma")
    # the centre pixel's residual, its plane's degrees of freedom undone (unwrap.reliability)
    return plane_residual_noise(e[interior], np.asarray(modulation)[interior], steps)["sigma_I"]


def _noise_sigma(noise_sigma, method, stack_hi, shifts_hi, phi_lo, phi_hi, pair, width, valid, B_hi):
    """(sigma, how): the intensity noise per frame - given, from the high stack's fit residuals (N >= 4)
    or from the phase residual of the traditional decode (3 steps: :func:`noise_from_phase`)."""
    if noise_sigma is not None:
        if not (math.isfinite(noise_sigma) and noise_sigma > 0):
            raise UnwrapError(f"noise_sigma must be finite and > 0 (grey levels), got {noise_sigma!r}")
        return float(noise_sigma), "given"
    if len(stack_hi) >= 4:
        return fit_noise_sigma(stack_hi, shifts_hi, valid), "fit residuals"
    from .temporal import decode_pair as traditional
    _, n0, ok0 = traditional(method, phi_lo, phi_hi, *pair, float(width), valid)
    return noise_from_phase(np.where(ok0, phi_hi + TWO_PI * n0, np.nan), ok0, B_hi, len(stack_hi)), "phase residual"


def global_bias_bound(lo, hi, valid, method: str, pair, orientation: str = "?"):
    """The bound on the prior's bias from global light (fringes of the high frequency, (H, W)) and
    the global / direct ratio (:mod:`unwrap.global_light`, the pattern's offset / amplitude
    estimated from the capture, black level 0) of an MF pair's wrapped phases ``lo``, ``hi``
    (:class:`unwrap.phase_shift.WrappedPhase`); (None, None) for MW / NT (the bound is the coarse
    phase's) or where the separation is refused (logged as a warning: the shipped data term is used)."""
    from .global_light import GlobalLightError, bias_bound

    if method != "mf":
        return None, None
    try:
        g = bias_bound(hi.A, hi.B, valid, offset_low=lo.A)     # the variant chosen on validation (docs/learned.md)
    except GlobalLightError as e:
        log.warning("orientation %s: no global-light bound (%s); the graph cut uses the prior's plain likelihood",
                    orientation, e)
        return None, None
    for n in g.notes:
        log.warning("orientation %s: %s", orientation, n)
    return g.fringes(*pair), g.ratio


def spatial_orientation(oc, method: str = "mf", *, model=None, use_gate: bool = True, min_modulation=None,
                        noise_sigma=None, check_prior: bool = True, camera_size=None, on_outside: str = "raise",
                        progress: bool = False, global_bound: bool = False) -> OrientationResult:
    """One orientation (:class:`unwrap.capture.OrientationCapture`) by the graph cut (module docstring).
    ``global_bound``: widen the prior's likelihood by the bound of :func:`global_bias_bound` (MF,
    prior data term only, else :class:`UnwrapError`; scale :data:`unwrap.spatial_orders.DEFAULTS` ``bias_scale``)."""
    if global_bound and (model is not None or method != "mf"):
        raise UnwrapError(f"global_bound: the bound widens the prior's data term of an MF pair; not with "
                          f"{'a model' if model is not None else f'method {method!r}'}")
    reader = FrameReader(camera_size)
    sets = sorted(oc.sets, key=lambda s: s.frequency)
    freqs = [float(s.frequency) for s in sets]
    i_lo, i_hi = _pair(method, freqs)
    w, stacks = {}, {}
    for i in (i_lo, i_hi):
        stacks[i] = reader.stack(sets[i].files)
        mm = check_min_modulation(min_modulation, stacks[i].dtype)
        w[i] = wrapped_phase(stacks[i], sets[i].shifts, min_modulation=mm)
    lo, hi = w[i_lo], w[i_hi]
    valid = lo.valid & hi.valid
    if not valid.any():
        raise UnwrapError(f"orientation {oc.orientation}: no valid pixel (modulation threshold {mm:.3g})")
    steps = (len(sets[i_lo].files), len(sets[i_hi].files))
    pair = (freqs[i_lo], freqs[i_hi])
    phi_lo, phi_hi = np.nan_to_num(lo.phase), np.nan_to_num(hi.phase)
    sigma, how = _noise_sigma(noise_sigma, method, stacks[i_hi], sets[i_hi].shifts, phi_lo, phi_hi, pair, oc.width,
                              valid, hi.B)
    s_lo, s_hi = phase_noise(lo.B, steps[0], sigma), phase_noise(hi.B, steps[1], sigma)
    extras, cost, conf, label = {}, None, None, f"{method}+graphcut"
    full = [float(np.iinfo(stacks[i].dtype).max) if np.issubdtype(stacks[i].dtype, np.integer) else 1.0
            for i in (i_lo, i_hi)]
    m_lo, m_hi = lo.B / full[0], hi.B / full[1]          # modulations as fractions of full scale
    if model is not None:
        from .learned.infer import unwrap_learned
        r = unwrap_learned(method, phi_lo, phi_hi, m_lo, m_hi, valid, pair, width=oc.width,
                           model=model, on_outside=on_outside, log_probs=True)
        cost, label = -r.log_probs, f"{method}+learned+graphcut"
    bound = None
    if model is None and global_bound:
        bound, ratio = global_bias_bound(lo, hi, valid, method, pair, oc.orientation)
        if bound is not None:
            extras["global_ratio"] = ratio.astype(np.float32)
            label += "+global"
    res = graphcut_orders(method, phi_lo, phi_hi, pair, valid, s_lo, s_hi, width=oc.width, cost=cost,
                          smoothness=DEFAULTS["smoothness_learned" if model is not None else "smoothness"],
                          outlier=DEFAULTS["outlier"], sigma_floor=DEFAULTS["sigma_floor"], bias_bound=bound,
                          max_correction=DEFAULTS["bias_max_correction"] if bound is not None else MAX_CORRECTION)
    order = res.order
    if model is not None:
        c = np.clip(res.correction + 2, 0, 4)
        conf = np.where(res.valid, np.exp(np.take_along_axis(r.log_probs, c[None], 0)[0]), 0.0)
        extras["confidence"] = conf.astype(np.float32)
    # the traditional decision's error probability, bias included (unwrap.decision_error)
    p_wrong = error_probability(res.p_wrong_traditional, res.prior, res.valid, m_lo, m_hi)
    if use_gate:
        g = GATE["Learned + graph cut" if model is not None else "Graph cut"]
        order = gate(order, res.order_traditional, res.valid, p_wrong, confidence=conf,
                     min_confidence=g["min_confidence"], min_p_wrong=g["min_p_wrong"])
        label += "+gate"
    ok = order >= 0
    phase = np.where(ok, phi_hi + TWO_PI * order, math.nan)
    phase, order, ok = constrain_to_pattern(np, phase, order, ok, pair[1], oc.width,
                                            pair_wrap_orders(method, *pair))   # MW / NT: one beat, as traditional
    phase = np.where(ok, phase, math.nan)
    out = Unwrapped(phase, np.where(ok, order, -1).astype(np.int32), ok, np.where(res.valid, res.prior, math.nan),
                    pair[1], label)
    checks = prior_check(Unwrapped(phase, order, res.valid, res.prior, pair[1], method))
    if check_prior:
        check_priors(checks, f"orientation {oc.orientation}, method {method} (spatial; the traditional prior)")
    extras["order_traditional"] = res.order_traditional.astype(np.int32)
    extras["p_wrong_traditional"] = res.p_wrong_traditional.astype(np.float32)
    extras["p_wrong_decision"] = p_wrong.astype(np.float32)
    changed = int(((order != res.order_traditional) & ok).sum())
    log.log(logging.INFO if progress else logging.DEBUG,
            "  [%s] %s: noise %.3g per frame (%s), %d of %d valid orders changed, graph cut %.2f s", oc.orientation,
            label, sigma, how, changed, int(ok.sum()), res.seconds)
    return OrientationResult(oc.orientation, oc.width, out, hi.B, hi.A, min_modulation=mm, noise_sigma=sigma,
                             prior_check=checks, extras=extras)


def unwrap_capture_spatial(folder, method: str = "mf", *, model=None, use_gate: bool = True, preset=None, pose=None,
                           min_modulation=None, noise_sigma=None, check_prior: bool = True,
                           on_outside: str = "raise", progress: bool = False, global_bound: bool = False) -> dict:
    """Every orientation of a capture folder by the graph cut: {"v": OrientationResult, ...}
    (``global_bound``: :func:`spatial_orientation`)."""
    cap = load_capture(folder, preset, pose)
    net = None
    if model is not None:
        from .learned.runtime import load_predictor
        net = load_predictor(model)      # torch or onnxruntime, loaded once
    out = {}
    for o, oc in cap.orientations.items():
        if not oc.sets:
            raise UnwrapError(f"orientation {o}: this capture holds Gray code only; the spatial stage needs "
                              "phase-shift frames of two frequencies")
        log.log(logging.INFO if progress else logging.DEBUG, "unwrap %s [%s] orientation %s, method %s + graph cut",
                cap.folder, cap.preset, o, method)
        out[o] = spatial_orientation(oc, method, model=net, use_gate=use_gate, min_modulation=min_modulation,
                                     noise_sigma=noise_sigma, check_prior=check_prior, camera_size=cap.camera_size,
                                     on_outside=on_outside, progress=progress, global_bound=global_bound)
    return out
