"""Per-frame intensity fluctuation (``frame_jitter = {offset, gain, seed}``): the light source's or
the exposure's fluctuation from frame to frame, exposure not synchronised with the projector's
refresh, auto-exposure. Measured on real captures by :mod:`unwrap.frame_jitter` (docs/unwrap.md,
"Per-frame intensity fluctuation (session 12)").

Frame k of the linear stack (K, H, W) (camera values before noise, 1.0 = full scale) becomes

    E'_k = g_k E_k + o_k * ref,    g_k = 1 + N(0, gain^2),  o_k = N(0, offset^2)

drawn per frame from ``numpy.random.default_rng(seed)`` (:func:`frame_factors`); ``ref`` is the
stack's background: the median over lit pixels (stack mean above 5 % of its maximum) of the
per-pixel mean of the stack. Applied after the light is mixed (global light, interreflection,
defocus; with the thin lens once, on the aperture average) and before the camera PSF's tail, the
sensor's noise, gain and response curve. With ``offset = gain = 0`` or the effect
absent the render is untouched (bit-identical). The offsets' first harmonic over a fringe set's
shifts biases its phase by about ``Im(z_o e^{-i phi}) / B`` rad (unwrap.frame_jitter).
"""
from __future__ import annotations

import numpy as np
import torch


def frame_factors(jitter, K: int) -> tuple:
    """(offsets (K,), gains (K,)) float64 of a ``synth.effects.spec.FrameJitter`` for K frames:
    offsets as fractions of the stack's background, gains around 1."""
    rng = np.random.default_rng(int(jitter.seed))
    o = rng.normal(0.0, 1.0, K) * jitter.offset
    g = 1.0 + rng.normal(0.0, 1.0, K) * jitter.gain
    return o, g


def background(images: torch.Tensor) -> float:
    """The stack's background (module docstring): a positive float, 0 for a black stack."""
    mean = images.to(torch.float64).mean(0)
    top = float(mean.max()) if mean.numel() else 0.0
    if top <= 0:
        return 0.0
    return float(mean[mean > 0.05 * top].median())


def apply_frame_jitter(images: torch.Tensor, jitter) -> torch.Tensor:
    """``g_k E_k + o_k ref`` of a (K, H, W) float stack (a new tensor of the same dtype)."""
    K = images.shape[0]
    o, g = frame_factors(jitter, K)
    ref = background(images)
    out = images.to(torch.float64) * torch.from_numpy(g)[:, None, None] + torch.from_numpy(o * ref)[:, None, None]
    return out.to(images.dtype)
