"""Training losses on masked fringe-order maps: MSE, a Fourier-domain term, cross-entropy.

All terms are computed in float32 (under mixed precision too): they are training signals of maps
whose values are a few units (corrections in [-2, 2] or orders / 64), where float32's 1e-7 relative
precision is far below any effect on the gradient; the FFT of a 640x480 map in float64 would cost
twice the time for nothing measurable.

Every term is a mean over the batch of per-sample values, each normalised by that sample's own
number of valid pixels (0 for a sample without any): so the mean over 2 processes of batch b
equals the mean over 1 process of batch 2b (distributed data parallel averages gradients).

Fourier term (``fourier_weighting``):

- ``"focal"``: the focal frequency loss of Jiang et al. (ICCV 2021), applied to the masked error
  map ``e = (prediction - target) * mask``: with ``E = FFT2(e)`` (orthonormal), the per-frequency
  distance ``|E|^2`` weighted by ``w = (|E| / max |E|)^alpha`` (per sample, not differentiated).
  Since ``FFT(pred) - FFT(target) = FFT(e)``, this is FFL on the two maps.
- ``"log_focal"``: the same with ``w = log(1 + |E|^alpha)`` normalised to max 1 (FFL's log option).
- ``"none"``: ``w = 1``. By Parseval this equals the MSE exactly (tested), which is why a plain
  spectral distance adds nothing: only the weighting makes the term different, putting the
  gradient on the spatial frequencies where the error spectrum is largest (the long-range,
  surface-wide error patterns rather than isolated pixels).

Cross-entropy (optional ``ce`` weight): on the output classes (the physics model's corrections
-K ... K, the prior-free model's orders 0 ... 64; :func:`unwrap.learned.features.class_targets`),
for the pixels with a class (index >= 0).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch.nn import functional as F

from .errors import ConfigError

WEIGHTINGS = ("focal", "log_focal", "none")


@dataclass(frozen=True)
class LossWeights:
    """Weights and form of the composite loss (see the module docstring)."""
    mse: float = 1.0
    fourier: float = 0.0
    fourier_weighting: str = "focal"
    fourier_alpha: float = 1.0
    ce: float = 0.0

    def __post_init__(self):
        for name in ("mse", "fourier", "ce", "fourier_alpha"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v >= 0 and v == v and v != float("inf")):
                raise ConfigError(f"loss.{name} = {v!r}: expected a finite number >= 0")
        if self.fourier_weighting not in WEIGHTINGS:
            raise ConfigError(f"loss.fourier_weighting = {self.fourier_weighting!r}: expected one of {WEIGHTINGS}")
        if self.mse + self.fourier + self.ce <= 0:
            raise ConfigError("loss: mse, fourier and ce weights are all 0; nothing to train")


def _per_sample_count(mask: torch.Tensor) -> torch.Tensor:
    return mask.flatten(1).sum(dim=1).to(torch.float32)


def _safe_mean(total: torch.Tensor, count: torch.Tensor) -> torch.Tensor:
    """mean over samples of total / count, a sample with count 0 giving 0."""
    return torch.where(count > 0, total / count.clamp(min=1.0), torch.zeros_like(total)).mean()


def masked_error(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(pred - target) where ``mask``, exactly 0 elsewhere (NaN-proof: ``where``, not a product)."""
    return torch.where(mask, pred.float() - target.float(), torch.zeros((), dtype=torch.float32))


def mse_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean over samples of the mean squared error over each sample's masked pixels."""
    e = masked_error(pred, target, mask)
    return _safe_mean((e * e).flatten(1).sum(dim=1), _per_sample_count(mask))


def fourier_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, *,
                 weighting: str = "focal", alpha: float = 1.0) -> torch.Tensor:
    """Weighted spectral distance of the masked maps (B, H, W); see the module docstring."""
    if weighting not in WEIGHTINGS:
        raise ConfigError(f"fourier weighting {weighting!r}: expected one of {WEIGHTINGS}")
    e = masked_error(pred, target, mask)
    E = torch.fft.fft2(e, norm="ortho")
    d = E.real ** 2 + E.imag ** 2
    if weighting == "none":
        w = torch.ones_like(d)
    else:
        with torch.no_grad():
            a = torch.sqrt(d) ** alpha
            if weighting == "log_focal":
                a = torch.log1p(a)
            w = a / a.flatten(1).amax(dim=1).clamp(min=1e-12)[:, None, None]
    return _safe_mean((w * d).flatten(1).sum(dim=1), _per_sample_count(mask))


def cross_entropy_loss(logits: torch.Tensor, classes: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Per-sample mean cross-entropy of ``logits`` (B, C, H, W) against the class indices
    ``classes`` (B, H, W) over the masked pixels with a class in [0, C)."""
    m = mask & (classes >= 0) & (classes < logits.shape[1])
    cls = torch.where(m, classes.long(), torch.zeros((), dtype=torch.long))
    ce = F.cross_entropy(logits.float(), cls, reduction="none")
    ce = torch.where(m, ce, torch.zeros((), dtype=ce.dtype))
    return _safe_mean(ce.flatten(1).sum(dim=1), _per_sample_count(m))


def composite_loss(weights: LossWeights, pred_map, target, mask, logits=None, classes=None):
    """(total, parts dict of floats): ``mse*MSE + fourier*FL + ce*CE`` on the order maps; the CE
    term needs ``logits`` (B, C, H, W) and ``classes`` (B, H, W) int64 (-1: no class)."""
    parts = {}
    total = torch.zeros((), dtype=torch.float32, device=pred_map.device)
    if weights.mse > 0:
        v = mse_loss(pred_map, target, mask)
        parts["mse"] = v
        total = total + weights.mse * v
    if weights.fourier > 0:
        v = fourier_loss(pred_map, target, mask, weighting=weights.fourier_weighting, alpha=weights.fourier_alpha)
        parts["fourier"] = v
        total = total + weights.fourier * v
    if weights.ce > 0 and logits is not None and classes is not None:
        v = cross_entropy_loss(logits, classes, mask)
        parts["ce"] = v
        total = total + weights.ce * v
    return total, {k: float(v.detach()) for k, v in parts.items()}
