"""Network inputs, training targets and the decoding of network outputs into fringe orders.

Two model kinds share everything but this file:

``physics`` (the physics-aware model, the paper's DP-TPU idea). Inputs, none of which depends on
the absolute high frequency ``f``:

====  =====================================================================================
ch    meaning
====  =====================================================================================
0     ``2 r`` with ``r = prior - round(prior)`` in [-0.5, 0.5]: how far the physics prior is from
      its decision, in periods of the high frequency. Noise-free it is 0 everywhere; where the
      low-frequency phase is biased (global illumination) it drifts smoothly and wraps through
      +-0.5 exactly where the traditional order goes wrong, *not* at the fringe edges (there the
      prior and its rounding jump together). It is the same quantity for MF and MW (fringe order
      estimate) and NT (residue), and the same at 16 or 96 periods.
1-2   ``2 r_s`` for the *smoothed prior*, whose coarse absolute phase (MF: the unit phase; MW, NT:
      the beat of the pair, absolute for pairs one period apart) is filtered by a local plane fit
      over the valid pixels of a box (:data:`SMOOTH_WINDOWS` = 7 and 15 px; the filtered baseline
      of :mod:`unwrap.learned.baselines`) before the rounding. A network cannot average the coarse
      phase itself: it only sees it wrapped into the prior, whose integer part it must not know
      (that is the frequency).
3-4   ``(round(prior_s) - order_traditional) / 2`` clipped to [-1, 1] for both windows: where the
      smoothed and the pixel's own prior disagree (noise that the filter removes, or a depth
      step the box smears); 0 for an NT pair without an absolute beat (there ``prior_s`` is the
      residue itself, not an order).
5-7   ``sin phi_h, cos phi_h, phi_h / pi``: the high wrapped phase, i.e. where the fringe edges are
      (the only places where the true order may change) and the spatial continuity to use.
8-9   modulation of the low / high pattern (x 4, clipped to 2): how noisy each phase is.
10    valid mask (1 / 0); every other channel is 0 at invalid pixels.
====  =====================================================================================

Output: ``2 K + 1`` logits per pixel for the integer correction ``c`` in ``[-K, K]`` (K = 2) added
to the traditional order (``round(prior)`` clipped for MF/MW, the lookup-table order for NT).
Why this generalises to an unseen frequency: the rounding already carries the absolute part of the
answer (0..f), which the network never has to produce; what is left is a small integer whose
meaning (one fringe too many or too few) is the same at every frequency, decided from inputs that
are themselves frequency-free. A network that outputs the order itself must map its inputs onto
0..48 when trained at 48 and has no way to output 0..96 (the prior-free row of table S5).
The softmax probability of the chosen correction is the per-pixel confidence.

``prior_free`` (the paper's DT-TPU baseline): the wrapped low and high phases (sin, cos, phase/pi),
both modulations, the valid mask and the method as three one-hot channels; :data:`ORDER_CLASSES`
(65) logits per pixel for the order itself, 0 ... 64 (classification: a regressed order divided by
64 had to reach 1/128 precision and stayed ~5 orders off after 1500 steps - 89 % wrong at the seen
48 periods; see docs/learned.md). The MSE / Fourier terms see the expected order / 64, the
confidence is the probability of the chosen order. Orders above 64 cannot be produced at all: the
point of table S5's unseen row.

Every input is made NaN-free here (``torch.where``, never a product with the mask), and pixels
with a non-finite input leave the valid mask, so NaN never reaches the network or the loss.
"""
from __future__ import annotations

import math

import torch

from .._xp import TIE_BAND
# the channel layout and its constants live in .channels (torch-free, shared with .fast_features)
from .channels import KINDS, METHOD_INDEX, MODULATION_GAIN, SMOOTH_WINDOWS, input_channels  # noqa: F401
from .errors import ModelError

ORDER_SCALE = 64.0
#: Order classes of the prior-free model: 0 ... ORDER_SCALE.
ORDER_CLASSES = int(ORDER_SCALE) + 1


def output_channels(kind: str, max_correction: int = 2) -> int:
    """Output channels: ``2 K + 1`` correction logits (physics) or :data:`ORDER_CLASSES` order
    logits (prior_free)."""
    input_channels(kind)
    return 2 * int(max_correction) + 1 if kind == "physics" else ORDER_CLASSES


def _round_order(x: torch.Tensor) -> torch.Tensor:
    """unwrap's rounding (ties down) on a tensor."""
    return torch.ceil(x - (0.5 + TIE_BAND))


def valid_mask(batch: dict) -> torch.Tensor:
    """(B, H, W) bool: the item's ``valid`` and every input finite at the pixel."""
    ok = batch["valid"].bool()
    for key in ("prior", "phase_low", "phase_high", "modulation_low", "modulation_high"):
        ok = ok & torch.isfinite(batch[key][:, 0])
    return ok


def smoothed_prior(batch: dict, ok: torch.Tensor, window: int):
    """((B, 1, H, W) float32, usable (B, 1, 1, 1) bool): the prior with the coarse phase
    plane-filtered over a ``window`` box (:func:`unwrap.learned.smoothing.smoothed_prior`; float64
    inside: ratio x phase reaches 600 rad at 96 periods). An NT pair without an absolute beat
    (not ``usable``) keeps its own prior. Uses the batch's ``method`` (B,) (MF without it)."""
    from .smoothing import smoothed_prior as _sp

    B = ok.shape[0]
    method = batch["method"].reshape(B, 1, 1, 1) if "method" in batch else torch.zeros(B, 1, 1, 1, dtype=torch.long)
    zero = torch.zeros((), dtype=torch.float64)
    okc = ok[:, None]
    prior_s, usable = _sp(torch.where(okc, batch["phase_low"].double(), zero),
                          torch.where(okc, batch["phase_high"].double(), zero),
                          batch["frequency_low"].reshape(B, 1, 1, 1), batch["frequency_high"].reshape(B, 1, 1, 1),
                          method == METHOD_INDEX["mf"], okc, window=window)
    return torch.where(usable, prior_s, batch["prior"].double()).to(torch.float32), usable


def make_inputs(batch: dict, kind: str, windows=SMOOTH_WINDOWS) -> tuple[torch.Tensor, torch.Tensor]:
    """(x float32 (B, C, H, W), valid bool (B, H, W)) from a collated batch of items; channels as
    :func:`unwrap.learned.channels.channel_slices` (``windows``: the smoothing boxes, px).

    ``batch`` holds the contract's tensors with a leading batch axis (``prior`` (B,1,H,W), ...);
    ``method`` (B,) int64 (0 mf, 1 mw, 2 nt) is needed by ``prior_free`` only.
    """
    ok = valid_mask(batch)
    okc = ok[:, None]
    zero = torch.zeros((), dtype=torch.float32)

    def clean(key):
        return torch.where(okc, batch[key].to(torch.float32), zero)

    phi_h = clean("phase_high")
    m_lo = torch.clamp(clean("modulation_low") * MODULATION_GAIN, 0.0, 2.0)
    m_hi = torch.clamp(clean("modulation_high") * MODULATION_GAIN, 0.0, 2.0)
    v = okc.to(torch.float32)
    if kind == "physics":
        prior = clean("prior")
        r = prior - _round_order(prior)
        trad = batch["order_traditional"][:, None].to(torch.float32)
        r_s, d = [], []
        for w in windows:
            prior_s, usable = smoothed_prior(batch, ok, w)
            prior_s = torch.where(okc, prior_s, zero)
            r_s.append(2.0 * (prior_s - _round_order(prior_s)))
            d.append(torch.where(okc & usable, torch.clamp((_round_order(prior_s) - trad) / 2.0, -1.0, 1.0), zero))
        chans = [2.0 * r, *r_s, *d, torch.sin(phi_h) * v, torch.cos(phi_h) * v, phi_h / math.pi, m_lo, m_hi, v]
    elif kind == "prior_free":
        phi_l = clean("phase_low")
        if "method" not in batch:
            raise ModelError("the prior-free model needs the batch's 'method' (0 mf, 1 mw, 2 nt)")
        onehot = torch.nn.functional.one_hot(batch["method"].long(), 3).to(torch.float32)
        onehot = onehot[:, :, None, None].expand(-1, -1, *phi_h.shape[-2:]) * v
        chans = [torch.sin(phi_l) * v, torch.cos(phi_l) * v, phi_l / math.pi,
                 torch.sin(phi_h) * v, torch.cos(phi_h) * v, phi_h / math.pi, m_lo, m_hi, v, onehot]
    else:
        raise ModelError(f"model kind {kind!r}: expected one of {KINDS}")
    return torch.cat(chans, dim=1), ok


def targets(batch: dict, kind: str, max_correction: int = 2) -> tuple[torch.Tensor, torch.Tensor]:
    """(target float32 (B, H, W), mask bool (B, H, W)) of the training loss.

    physics: the correction ``order_true - order_traditional`` clipped to [-K, K]; prior_free: the
    true order / ``ORDER_SCALE``. ``mask``: valid inputs and a true order (>= 0).
    """
    ok = valid_mask(batch) & (batch["order_true"] >= 0)
    true = batch["order_true"]
    if kind == "physics":
        c = (true - batch["order_traditional"]).clamp(-max_correction, max_correction)
        t = c.to(torch.float32)
    elif kind == "prior_free":
        t = true.to(torch.float32) / ORDER_SCALE
    else:
        raise ModelError(f"model kind {kind!r}: expected one of {KINDS}")
    return torch.where(ok, t, torch.zeros((), dtype=torch.float32)), ok


def class_targets(batch: dict, kind: str, max_correction: int = 2) -> torch.Tensor:
    """(B, H, W) int64 class index of the cross-entropy term, -1 where not trained (invalid inputs,
    no true order, or an order the prior-free model cannot output).

    physics: the correction clipped to [-K, K], plus K; prior_free: the true order (0 ... 64).
    """
    target, ok = targets(batch, kind, max_correction)
    if kind == "physics":
        cls = target.round().long() + max_correction
    else:
        cls = batch["order_true"].long()
        ok = ok & (cls < ORDER_CLASSES)
    return torch.where(ok, cls, torch.full_like(cls, -1))


def expected_map(out: torch.Tensor, kind: str, max_correction: int = 2) -> torch.Tensor:
    """The differentiable fringe-order map the loss compares with :func:`targets` (B, H, W).

    physics: the expected correction ``sum_c p_c c`` under the softmax; prior_free: the expected
    order ``sum_k p_k k`` / ORDER_SCALE.
    """
    if kind == "physics":
        c = torch.arange(-max_correction, max_correction + 1, dtype=out.dtype, device=out.device)
    else:
        c = torch.arange(out.shape[1], dtype=out.dtype, device=out.device) / ORDER_SCALE
    return (torch.softmax(out, dim=1) * c[None, :, None, None]).sum(dim=1)


def decode(out: torch.Tensor, batch: dict, kind: str, max_correction: int = 2):
    """Network output -> (order int64 (B,H,W) -1 invalid, confidence float32 (B,H,W) in [0, 1]).

    physics: the most probable correction added to the traditional order, clipped to
    [0, round(f_high)]; confidence = its probability. prior_free: the most probable order class;
    confidence = its probability.
    """
    ok = valid_mask(batch)
    kmax = torch.floor(batch["frequency_high"].to(torch.float64) + 0.5).to(torch.int64)[:, None, None]
    p = torch.softmax(out.float(), dim=1)
    conf, cls = p.max(dim=1)
    order = batch["order_traditional"] + cls - max_correction if kind == "physics" else cls
    order = torch.minimum(order.clamp(min=0), kmax)
    order = torch.where(ok, order, torch.full_like(order, -1))
    return order, torch.where(ok, conf, torch.zeros_like(conf))
