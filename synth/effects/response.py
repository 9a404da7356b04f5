"""The camera after the lens: the PSF's wide tail on the sensor irradiance and the camera's
response curve. Both work on the linear stack (K, H, W) float32 of synth.renderer.render.

PSF tail (``camera_psf_tail = {fraction, sigma_px}``): stray light inside the lens and the
sensor (veiling glare, diffusion in the sensor stack) spreads a small fraction of the light
that reaches the sensor plane over a wide area. It acts on the irradiance of the sensor plane,
which is already what the lens delivered, whatever the depth the light came from (the depth
mixing happened in front of the lens: synth.effects.thin_lens), so here a convolution of the
image *is* the physics: ``E' = (1 - a) E + a (G_sigma * E)`` with ``G`` a normalised Gaussian of
``sigma_px`` pixels, zero outside the image (light spread beyond the sensor is lost, light from
outside the field is not modelled). Its transfer function is ``(1 - a) + a exp(-2 pi^2 sigma^2
|nu|^2)`` (nu in cycles/px): fringes lose contrast by up to ``a``; the phase is biased where the
image's brightness and fringe phase vary within ``sigma`` (outlines, shadows).

Response curve (``camera_gamma``, g): the camera's output is ``clip(gain * v, 0, saturation)^g``
(v the linear value after noise), then quantised. Applied after everything that mixes light
(defocus, PSF, interreflection) and after the noise, which is linear in electrons. The
projector's curve is ``projector_gamma`` (applied to the pattern before projection,
synth.renderer.projection).
"""
from __future__ import annotations

import math

import torch


def psf_tail(images: torch.Tensor, fraction: float, sigma_px: float) -> torch.Tensor:
    """``(1 - fraction) E + fraction (G * E)`` of a (K, H, W) stack, G the normalised Gaussian of
    ``sigma_px``, zero padding (by FFT over an image padded by 4 sigma). Returns a new tensor."""
    K, H, W = images.shape
    r = int(math.ceil(4 * sigma_px))
    Hp, Wp = H + 2 * r, W + 2 * r
    x = torch.zeros((K, Hp, Wp), dtype=torch.float64)
    x[:, r:r + H, r:r + W] = images
    fy = torch.fft.fftfreq(Hp, dtype=torch.float64)
    fx = torch.fft.rfftfreq(Wp, dtype=torch.float64)
    # the transfer function of the continuous Gaussian (its sampled kernel sums to 1 only for
    # sigma >~ 0.5 px; the tail is wide)
    G = torch.exp(-2 * math.pi ** 2 * sigma_px ** 2 * (fy[:, None] ** 2 + fx[None, :] ** 2))
    blurred = torch.fft.irfft2(torch.fft.rfft2(x) * G, s=(Hp, Wp))[:, r:r + H, r:r + W]
    return ((1.0 - fraction) * images.to(torch.float64) + fraction * blurred).to(images.dtype)


def camera_response(images: torch.Tensor, gamma: float, gain: float, saturation: float) -> torch.Tensor:
    """``clip(gain * v, 0, saturation) ** gamma`` in place on a float stack."""
    if gain != 1.0:
        images.mul_(gain)
    return images.clamp_(0.0, saturation).pow_(gamma)
