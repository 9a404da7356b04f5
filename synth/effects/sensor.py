"""The camera side after the scene: defocus, Poisson-Gaussian noise, gain, saturation and
quantisation. Works on the stack (K, H, W).

float32 here: the images carry at most 16-bit signals and float32's 24-bit mantissa is 256x finer
than the finest quantisation step, while halving memory and doubling convolution speed; the
geometry and phase that produced them stayed float64.
"""
from __future__ import annotations

import math

import torch

from ..renderer.projection import _blur_levels, _level_weights


def camera_defocus(images: torch.Tensor, sigma: torch.Tensor, levels: int = 6) -> torch.Tensor:
    """Depth-dependent blur: images (K,H,W), per-pixel sigma (H,W) px -> blurred (K,H,W).

    The stack is blurred at ``levels`` sigmas from 0 to max(sigma); each pixel interpolates
    between the two levels around its own sigma (a gather approximation of the thin-lens
    scatter, exact on surfaces of constant depth)."""
    smax = float(sigma.max())
    if smax < 1e-3:
        return images
    lv = torch.linspace(0, smax, levels, dtype=torch.float64)
    i, w = _level_weights(sigma.to(torch.float64), lv)
    i, w = i.reshape(-1), w.reshape(-1).to(images.dtype)
    K, H, W = images.shape
    out = torch.zeros((K, H * W), dtype=images.dtype)
    for k, blurred in enumerate(_blur_levels(images, [(float(s), float(s)) for s in lv])):
        wk = torch.where(i == k, 1 - w, torch.zeros_like(w)) + torch.where(i + 1 == k, w, torch.zeros_like(w))
        if bool((wk > 0).any()):
            out.addcmul_(blurred.reshape(K, -1), wk)  # dense: cheaper than gathering the pixels
    return out.reshape(K, H, W)


POISSON_BELOW_E = 50  # electrons: exact Poisson shot noise below, its normal approximation above


def add_noise(images: torch.Tensor, noise, generator: torch.Generator) -> torch.Tensor:
    """Poisson-Gaussian noise in electrons, in place: ``e = value * full_well``; shot noise
    exact (Poisson) between 0 and 50 electrons, its normal approximation N(e, e) above; plus
    N(0, read^2).

    Contiguous float32 stacks on the CPU run ``synth.effects._noise_kernel`` (when numba is
    installed): the same model and float32 arithmetic in one fused pass, with its own random
    numbers (ziggurat normals, Poisson by inversion, one counter-seeded stream per block of
    pixels, the seed drawn from ``generator``), so its noise is another draw of the same
    distribution than the torch version's; statistics checked in tests/test_synth_reference.py."""
    if (images.device.type == "cpu" and images.dtype == torch.float32 and images.is_contiguous()
            and _noise_kernel_available()):
        from ._noise_kernel import add_noise_numba

        seed = int(torch.randint(0, 1 << 62, (1,), generator=generator, dtype=torch.int64))
        add_noise_numba(images.view(-1).numpy(), seed, float(noise.full_well_e), float(noise.read_noise_e),
                        float(POISSON_BELOW_E))
        return images
    return _add_noise_torch(images, noise, generator)


def _noise_kernel_available() -> bool:
    try:
        from . import _noise_kernel  # noqa: F401
    except ImportError:
        return False
    return True


def _add_noise_torch(images: torch.Tensor, noise, generator: torch.Generator) -> torch.Tensor:
    """The torch version of :func:`add_noise` (any device and dtype)."""
    e = images.clamp_(min=0).mul_(noise.full_well_e)
    # dark pixels (e = 0: unlit, shadowed) draw Poisson(0) = 0 exactly: read noise only
    low = (e > 0) & (e < POISSON_BELOW_E)
    z = torch.randn(e.shape, generator=generator, dtype=e.dtype)
    shot_low = torch.poisson(e[low].to(torch.float64), generator=generator).to(e.dtype) if bool(low.any()) else None
    std = (e + noise.read_noise_e ** 2).sqrt_()
    if shot_low is not None:
        std[low] = noise.read_noise_e
        e[low] = shot_low
    e.add_(z.mul_(std))
    return e.div_(noise.full_well_e)


def quantise(images: torch.Tensor, bits: int, gain: float = 1.0, saturation: float = 1.0) -> torch.Tensor:
    """Linear values -> integer counts in [0, 2^bits - 1] after gain and saturation (uint8 for 8
    bits, int32 above). Works in place on ``images`` (float) to avoid 100 MB temporaries."""
    top = (1 << bits) - 1
    v = images
    if gain != 1.0:
        v.mul_(gain)
    v.clamp_(0.0, saturation).mul_(top).round_().clamp_(0, top)
    return v.to(torch.uint8 if bits <= 8 else torch.int32)


# -- the full well that gives a noise level (the sensor model above, solved for its one unknown) --

def predicted_phase_noise(A_lin, B_lin, full_well: float, steps: int, bits: int, read_noise_e: float) -> float:
    """Median N-step phase noise (rad) for Poisson-Gaussian noise plus quantisation, per pixel
    ``sqrt(2/N) sigma_I / B`` with ``sigma_I^2 = (A FW + read^2) / FW^2 + q^2 / 12``, q = 1 count
    (``A_lin``, ``B_lin``: linear full-scale background and modulation of the pixels)."""
    import numpy as np

    q = 1.0 / ((1 << bits) - 1)
    var = (A_lin * full_well + read_noise_e ** 2) / full_well ** 2 + q * q / 12
    return float(np.median(np.sqrt(2.0 / steps) * np.sqrt(var) / B_lin))


def solve_full_well(A_lin, B_lin, target: float, steps: int, bits: int, read_noise_e: float) -> float | None:
    """Full well (electrons) whose :func:`predicted_phase_noise` is the ``target`` (rad), by
    bisection in log space; None if even a noise-free camera (quantisation only) is noisier."""
    lo, hi = 1.0, 1e12
    if predicted_phase_noise(A_lin, B_lin, hi, steps, bits, read_noise_e) >= target:
        return None
    for _ in range(200):
        mid = math.sqrt(lo * hi)
        if predicted_phase_noise(A_lin, B_lin, mid, steps, bits, read_noise_e) > target:
            lo = mid
        else:
            hi = mid
        if hi / lo < 1 + 1e-6:
            break
    return float(hi)


def shot_noise_full_well(modulation: float, sigma_I: float) -> float:
    """Full well (electrons at full scale) whose shot noise alone gives the intensity noise
    ``sigma_I`` at full-contrast fringes (``sigma_I^2 ~ I / full_well`` with ``I ~ B``):
    ``B / sigma_I^2``. A first guess where the read noise and quantisation are unknown."""
    return float(modulation / max(sigma_I, 1e-6) ** 2)
