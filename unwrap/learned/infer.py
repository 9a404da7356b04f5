"""Apply a trained model: wrapped phases in, fringe order and per-pixel confidence out.

SYNOPSIS

    from unwrap.learned import unwrap_learned
    r = unwrap_learned("mf", phi_1, phi_48, m_1, m_48, valid, (1, 48), width=912, model="learned")
    r.order, r.confidence, r.order_traditional, r.frequency_check

``model``: ``"learned"`` (the checkpoint shipped with sltwin, :func:`shipped_model_path`), a
checkpoint path (``.pt``: torch; ``.onnx``: onnxruntime, from ``calib export-model``), a
``(model, checkpoint)`` pair from :func:`unwrap.learned.checkpoint.load_model`, or a predictor of
:mod:`unwrap.learned.runtime`. A file is loaded once per process and reused. The inputs and the
decoding are numpy (:mod:`unwrap.learned.fast_features`): this module does not import torch,
and an ``.onnx`` model runs without it.

Frequency range (:func:`check_frequency_range`): what the network sees depends on the frequency
only through two quantities, and both are checked before it runs:

- the noise gain of the prior, the ratio ``R = f_hi / f_coarse`` (MF: ``f_hi / f_lo``; MW / NT: ``f_hi``
  over the beat). Relative to the ratio it was trained at, up to 2.5x is the tested range
  (table S5's unseen f = 96 is 2x), 2.5-4x runs with a :class:`FrequencyRangeWarning`, more than 4x
  (or less than 1/8) is refused: the prior's noise alone then decides most pixels.
- the fringe period on the camera, measured from the high wrapped phase (median over valid
  pixels of ``2 pi / |grad phi|``, on one row in 4 unless that lands near the threshold:
  :func:`measured_period_px`): below :data:`MIN_PERIOD_PX` pixels the phase is aliased and
  no order can be trusted, so it is refused.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from .. import _xp
from ..memory import trim_heap
from ..methods import coarse_ratio
from ..temporal import decode_pair
from . import fast_features as FF
from .beat_window import wrap_orders
from .errors import FrequencyRangeWarning, ModelError
from .runtime import load_predictor, shipped_model_path  # noqa: F401  (shipped_model_path: public here)

#: Refuse fringe periods on the camera shorter than this (px).
MIN_PERIOD_PX = 3.0
#: Ratio factor (relative to training) beyond which a warning / a refusal happens.
WARN_RATIO, MAX_RATIO, MIN_RATIO = 2.5, 4.0, 1.0 / 8.0

#: Frame sizes whose forward has been preceded by a heap trim in this process. Once per size: the
#: next frame of a size reuses the freed blocks of the last one, and trimming them again would
#: fault them back in (~10k page faults, ~40 MB, per 640 x 480 frame: more system time than the
#: decode). ``calib unwrap --model`` at 900 x 700 peaks at the same ~500 MB with a trim per
#: orientation, one per size, or none (docs/speed.md, "The learned path on 2 CPU cores").
#: A predictor whose ``trim_every_frame`` is true (onnxruntime's: its arena, kept from the first
#: frame, does not reuse the heap's freed blocks, so a second frame without a trim holds both;
#: ``calib unwrap --model model.onnx`` at 900 x 700: ~355 MB against ~320 MB with a trim per
#: orientation) is trimmed before every forward.
_TRIMMED: dict = {}     # (H, W) -> whether glibc released memory then


def resolve_model(model, device="cpu"):
    """(network in eval mode, checkpoint dict) of a torch model: "learned", a ``.pt`` path or a
    (model, ck) pair (loaded once per process: :func:`unwrap.learned.runtime.load_predictor`)."""
    if isinstance(model, tuple):
        return model
    pred = load_predictor(model, device)
    if pred.backend != "torch":
        raise ModelError(f"{model}: an {pred.backend} model; this needs a torch checkpoint (.pt)")
    return pred.net, pred.ck


#: Row step of the range check's sample (:func:`fringe_period_px`): one row in 4, staggered.
PERIOD_ROW_STEP = 4
#: Fewest sampled pixel pairs from which the sample's median stands for the frame's (else: every row).
PERIOD_MIN_SAMPLES = 4096
#: Relative band around :data:`MIN_PERIOD_PX` inside which the range check measures every row, so
#: that its decision is the full frame's wherever the sample's median is within 25 % of the frame's.
PERIOD_RECHECK_BAND = 0.25


def fringe_period_px(phase_high, valid, row_step: int = 1) -> float:
    """Median fringe period on the camera (px) from wrapped-phase differences between neighbours:
    ``2 pi / median |(wrap(dx), wrap(dy))|`` over the pixels valid with their right and lower
    neighbours (the differences taken at those pixels only: a third of the full-frame passes).

    ``row_step`` > 1: over the rows ``k step + (k mod step)`` only (their lower neighbours one row down),
    where they hold at least :data:`PERIOD_MIN_SAMPLES` such pixels (else every row): the range check's
    estimate (:func:`check_frequency_range`; on the test captures and the 640 x 480 speed ramp within
    1 % of the full frame's, tests/test_learned_whole_path.py)."""
    phi = np.asarray(phase_high, dtype=np.float64)
    v = np.asarray(valid, dtype=bool)
    if row_step > 1 and phi.ndim == 2 and phi.shape[0] > row_step:
        # rows k step + (k mod step): every residue mod step (and mod 2) as often as in the frame, so
        # that a defect every 2nd or step-th row weighs in the sample as in the frame (rows 0, step,
        # 2 step, ... alone saw every step-th row's pairs or none of them)
        k = np.arange(-(-(phi.shape[0] - 1) // row_step))
        rows = k * row_step + k % row_step
        rows = rows[rows < phi.shape[0] - 1]
        p0, v0, p1, v1 = phi[rows], v[rows], phi[rows + 1], v[rows + 1]
        ok = v0[:, :-1] & v0[:, 1:] & v1[:, :-1]
        if np.count_nonzero(ok) >= PERIOD_MIN_SAMPLES:
            return _median_period(p0[:, :-1], p0[:, 1:], p1[:, :-1], ok)
    ok = v[:-1, :-1] & v[:-1, 1:] & v[1:, :-1]
    return _median_period(phi[:-1, :-1], phi[:-1, 1:], phi[1:, :-1], ok)


def _median_period(p00, p01, p10, ok) -> float:
    """``2 pi / median |(wrap(p01 - p00), wrap(p10 - p00))|`` over ``ok`` (NaN: no pixel)."""
    if not ok.any():
        return float("nan")
    p = p00[ok]
    gx = _xp.wrap(p01[ok] - p)
    gy = _xp.wrap(p10[ok] - p)
    med = float(np.median(np.hypot(gx, gy)))
    return _xp.TWO_PI / med if med > 0 else float("inf")


def measured_period_px(phase_high, valid) -> float:
    """The range check's fringe period (px): :func:`fringe_period_px` on one row in
    :data:`PERIOD_ROW_STEP` (~1/4 of the time), over every row where that estimate lies
    within :data:`PERIOD_RECHECK_BAND` of :data:`MIN_PERIOD_PX` (the refusal's threshold): the
    decision is then the full frame's wherever the sample's median is within 25 % of the frame's
    (a sample at ``(1 + e) p`` with ``|e| < 0.25`` lies outside the band only on the side of 3 px
    that ``p`` itself lies on)."""
    p = fringe_period_px(phase_high, valid, PERIOD_ROW_STEP)
    if (1.0 - PERIOD_RECHECK_BAND) * MIN_PERIOD_PX < p < (1.0 + PERIOD_RECHECK_BAND) * MIN_PERIOD_PX:
        return fringe_period_px(phase_high, valid)
    return p


def check_frequency_range(meta: dict, method: str, frequencies, phase_high=None, valid=None,
                          *, on_outside: str = "raise") -> dict:
    """Compare a (method, frequency pair) with what the model was trained on (module docstring).

    RETURNED VALUE: {"ratio", "trained_ratio", "ratio_factor", "period_px", "status"} with status
    "ok", "warn" or "refused". ``on_outside``: "raise" (:class:`ModelError` when refused), "warn"
    (a warning instead) or "ignore"; "warn" status always issues a :class:`FrequencyRangeWarning`.
    """
    f_lo, f_hi = (float(f) for f in frequencies)
    trained = meta.get("frequencies", {}).get(method)
    if trained is None:
        known = sorted(meta.get("frequencies", {}))
        raise ModelError(f"the model was not trained for method {method!r} (trained: {known})")
    r, r0 = coarse_ratio(method, f_lo, f_hi), coarse_ratio(method, *map(float, trained))
    fac = r / r0
    period = measured_period_px(phase_high, valid) if phase_high is not None else float("nan")
    status, why = "ok", ""
    if fac > MAX_RATIO or fac < MIN_RATIO:
        status, why = "refused", (f"frequency ratio {r:g} is {fac:.2f}x the trained {r0:g} (allowed "
                                  f"{MIN_RATIO:g}x to {MAX_RATIO:g}x)")
    elif period == period and period < MIN_PERIOD_PX:
        status, why = "refused", f"fringe period on the camera {period:.2f} px < {MIN_PERIOD_PX} px (aliased)"
    elif fac > WARN_RATIO:
        status, why = "warn", f"frequency ratio {r:g} is {fac:.2f}x the trained {r0:g}: outside the tested range"
    out = {"ratio": r, "trained_ratio": r0, "ratio_factor": fac, "period_px": period, "status": status,
           "reason": why}
    msg = f"{method} ({f_lo:g}, {f_hi:g}): {why}"
    if status == "refused" and on_outside == "raise":
        raise ModelError(msg + "; the model cannot unwrap this reliably (use the traditional method)")
    if status == "warn" or (status == "refused" and on_outside == "warn"):
        warnings.warn(msg, FrequencyRangeWarning, stacklevel=2)
    return out


def predict(model, ck: dict, batch: dict, inputs=None):
    """(order int64 (B,H,W) -1 invalid, confidence float32 (B,H,W)) of a collated torch batch
    (training / evaluation; torch features of :mod:`unwrap.learned.features`).

    ``inputs``: the batch's ``features.make_inputs(batch, kind)`` when already computed (several
    models of one kind on the same data)."""
    import torch

    from . import features as Fe

    kind, K = ck["arch"]["kind"], ck["arch"]["max_correction"]
    dev = next(model.parameters()).device
    with torch.inference_mode():
        batch = {k: (v.to(dev) if torch.is_tensor(v) else v) for k, v in batch.items()}
        x = (inputs if inputs is not None else Fe.make_inputs(batch, kind))[0].to(dev)
        return Fe.decode(model(x).float(), batch, kind, K)


def _orders_on_device(pred, method, prior, phi_lo, phi_hi, m_lo, m_hi, order_trad, valid, freqs):
    """(order int64 (H, W), confidence float32 (H, W)) with the inputs, the forward and the decode on
    a torch predictor's device: the training's torch features and decode (:mod:`.features`), which
    give :mod:`.fast_features`' orders up to float32 ties for MF (tests/test_learned_deploy.py,
    tests/test_learned_precision.py). Inputs float32 as in training (the smoothing inside is float64)."""
    import torch

    from . import features as Fe

    dev = pred.device

    def f32(a):
        # as fast_features: NaN -> 0, +-inf stays infinite (features.valid_mask drops the pixel; a plain
        # nan_to_num would make it a float64 max that overflows float32 with a warning)
        a = np.nan_to_num(np.asarray(a, dtype=np.float64), nan=0.0, posinf=np.inf, neginf=-np.inf)
        a = np.where(valid, a, 0.0).astype(np.float32)
        return torch.from_numpy(a)[None, None].to(dev)

    batch = {"prior": f32(prior), "phase_low": f32(phi_lo), "phase_high": f32(phi_hi),
             "modulation_low": f32(m_lo), "modulation_high": f32(m_hi),
             "order_traditional": torch.from_numpy(np.asarray(order_trad, dtype=np.int64))[None].to(dev),
             "valid": torch.from_numpy(np.asarray(valid, dtype=bool))[None].to(dev),
             "frequency_low": torch.tensor([float(freqs[0])], dtype=torch.float64, device=dev),
             "frequency_high": torch.tensor([float(freqs[1])], dtype=torch.float64, device=dev),
             "method": torch.tensor([Fe.METHOD_INDEX[method]], device=dev)}
    kind, K = pred.arch["kind"], int(pred.arch["max_correction"])
    with torch.inference_mode():
        x, _ = Fe.make_inputs(batch, kind)
        order, conf = Fe.decode(pred.forward(x), batch, kind, K)
        return order[0].cpu().numpy(), conf[0].cpu().numpy()


def _decode_pair(method, phi_lo, phi_hi, f_lo, f_hi, width, valid):
    """:func:`unwrap.temporal.decode_pair` of the NaN-cleaned phases (``valid`` excludes the pixels
    that are not finite): for MF its C replica where built and checked (:mod:`._features_c`, the
    same bits, ~5x faster, no cleaned copies), else numpy."""
    if method == "mf" and phi_hi.ndim == 2 and FF.native_features():
        from . import _features_c as FC

        return FC.mf_prior(phi_lo, phi_hi, valid, f_lo, f_hi, width, FF.native_features())
    return decode_pair(method, np.nan_to_num(phi_lo), np.nan_to_num(phi_hi), f_lo, f_hi, width, valid)


@dataclass
class LearnedResult:
    """Output of :func:`unwrap_learned` (numpy, camera image shape)."""
    order: np.ndarray            # int64, -1 where invalid
    confidence: np.ndarray       # float32 in [0, 1], 0 where invalid
    order_traditional: np.ndarray
    prior: np.ndarray            # float64, 0 where invalid
    valid: np.ndarray
    frequency_check: dict = field(default_factory=dict)
    log_probs: np.ndarray | None = None   # float64 (2K+1, H, W) class log-probabilities (``log_probs=True``)


def unwrap_learned(method: str, phase_low, phase_high, modulation_low, modulation_high, valid, frequencies, *,
                   width: float, model="learned", on_outside: str = "raise", log_probs: bool = False) -> LearnedResult:
    """Fringe order of the high frequency from one orientation's wrapped phases, by the network.

    ARGUMENTS: method ("mf", "mw", "nt"); wrapped phases (rad, (H, W), NaN allowed where invalid);
    modulations (fraction of full scale); valid (H, W) bool; frequencies (low, high); width =
    projector pixels across the fringes; model (module docstring); on_outside (see
    :func:`check_frequency_range`); log_probs: also return the per-pixel log-probabilities of the
    correction classes -K..K (the data term of :mod:`unwrap.spatial_orders`; physics-aware models).
    """
    pred = load_predictor(model)
    kind, K = pred.arch["kind"], int(pred.arch["max_correction"])
    f_lo, f_hi = (float(f) for f in frequencies)
    phi_lo, phi_hi = (np.asarray(a, dtype=np.float64) for a in (phase_low, phase_high))
    valid = np.asarray(valid, dtype=bool) & np.isfinite(phi_lo) & np.isfinite(phi_hi)
    if phi_lo.shape != phi_hi.shape or valid.shape != phi_hi.shape or phi_hi.ndim != 2:
        raise ModelError(f"phases {phi_lo.shape}, {phi_hi.shape} and valid {valid.shape}: expected one (H, W) shape")
    check = check_frequency_range(pred.meta, method, (f_lo, f_hi), phi_hi, valid, on_outside=on_outside)
    prior, order_trad, valid = _decode_pair(method, phi_lo, phi_hi, f_lo, f_hi, float(width), valid)
    if getattr(pred, "features_on_device", False) and method == "mf" and not log_probs:
        # MF only: MW / NT inputs filter the beat as a periodic phase (unwrap.learned.beat_window), which
        # the training's torch features do not; those build their inputs in numpy, the forward on the device
        order, conf = _orders_on_device(pred, method, prior, phi_lo, phi_hi, modulation_low, modulation_high,
                                        order_trad, valid, (f_lo, f_hi))
        return LearnedResult(order, conf, order_trad, prior, valid, check)
    # in the layout the predictor's forward takes without a copy, padded to its size multiple
    x, ok = FF.make_inputs(kind, method, prior, phi_lo, phi_hi, modulation_low, modulation_high, order_trad, valid,
                           (f_lo, f_hi), layout=getattr(pred, "input_layout", "nchw"),
                           multiple=getattr(pred, "multiple", 1))
    del modulation_low, modulation_high        # freed before the forward where the caller passed temporaries
    H, W = ok.shape
    if hasattr(pred, "prepare"):       # as the graph takes it (already padded: no copy)
        x = pred.prepare(x)
    if (H, W) not in _TRIMMED or getattr(pred, "trim_every_frame", False):
        # the forward is the peak: the maps freed so far leave the heap first, once per frame size
        # (:data:`_TRIMMED`), or every frame for onnxruntime
        _TRIMMED[(H, W)] = trim_heap()
    logits = pred.logits(x)[..., :H, :W]
    del x                                                            # the input (C x H x W float32) is not needed after
    order, conf = FF.decode(logits, order_trad, ok, f_hi, kind, K, wrap_orders(method, f_lo, f_hi))
    if not log_probs:
        return LearnedResult(order, conf, order_trad, prior, valid, check)
    if kind != "physics":
        raise ModelError("log_probs: only a physics-aware model outputs order-correction classes")
    z = np.asarray(logits[0], dtype=np.float64)                     # (2K + 1, H, W)
    z = z - z.max(axis=0, keepdims=True)
    lp = z - np.log(np.exp(z).sum(axis=0, keepdims=True))
    return LearnedResult(order, conf, order_trad, prior, valid, check, lp)
