"""Spatial filtering of a coarse absolute phase over the valid pixels of a box (torch, float64).

``fit="plane"`` (default): a least-squares plane through the valid pixels of the
``window x window`` box around each pixel, evaluated at the pixel (first-order normalised
convolution). Unlike the box mean it has no bias where the box is cut by the edge of the valid
region (an object's silhouette, a shadow, the image border): the mean of a linear phase over a
one-sided box is shifted by a quarter of the window times the gradient, which at 48 periods is
already a third of a fringe. ``fit="mean"``: the plain masked mean. Where the box has fewer than
3 valid pixels, or they are collinear, the plane falls back to the mean.

Both remove independent pixel noise (about 1/window of its standard deviation) but not a bias
shared by the box, and both mix surfaces across a depth step.

SYNOPSIS

    >>> import torch
    >>> from unwrap.learned.smoothing import smooth_phase
    >>> y, x = torch.meshgrid(torch.arange(20.0), torch.arange(30.0), indexing="ij")
    >>> Phi = (0.01 * x + 0.02 * y)[None, None].double()
    >>> valid = (x < 12)[None, None]
    >>> out = smooth_phase(Phi, valid, 7)
    >>> bool(torch.allclose(out[valid], Phi[valid]))       # exact on a plane, even at the edge
    True
"""
from __future__ import annotations

import torch
from torch.nn import functional as F

FITS = ("plane", "mean")


def _box_sum(x: torch.Tensor, window: int) -> torch.Tensor:
    """Sum over the window x window box centred on each pixel (zeros outside the image), by
    running sums along each axis (O(1) per pixel whatever the window; float64 keeps the
    differences exact to ~1e-16 of the row sums)."""
    pad = window // 2
    for dim in (-1, -2):
        n = x.shape[dim]
        pads = [0, 0, 0, 0]
        pads[0 if dim == -1 else 2] = pad + 1
        pads[1 if dim == -1 else 3] = pad
        c = torch.cumsum(F.pad(x, pads), dim=dim)
        x = c.narrow(dim, window, n) - c.narrow(dim, 0, n)
    return x


def smooth_phase(Phi: torch.Tensor, valid: torch.Tensor, window: int = 15, fit: str = "plane") -> torch.Tensor:
    """Filtered ``Phi`` (B, 1, H, W) over ``valid`` (B, 1, H, W) bool; float64; invalid pixels keep ``Phi``.

    ``window``: odd box size in pixels (an even one is made odd by adding 1).
    """
    if fit not in FITS:
        raise ValueError(f"fit {fit!r}: expected one of {FITS}")
    window = int(window) | 1
    f64 = torch.float64
    v = valid.to(f64)
    P = torch.where(valid, Phi.to(f64), torch.zeros((), dtype=f64))
    S0 = _box_sum(v, window)
    SP = _box_sum(P, window)
    mean = torch.where(S0 > 0.5, SP / S0.clamp(min=1.0), P)
    if fit == "mean":
        return torch.where(valid, mean, Phi.to(f64))
    H, W = Phi.shape[-2:]
    y, x = torch.meshgrid(torch.arange(H, dtype=f64, device=Phi.device),
                          torch.arange(W, dtype=f64, device=Phi.device), indexing="ij")
    # moments about each box's own centre pixel: sum v (x' - x)^i (y' - y)^j
    Sx, Sy = _box_sum(v * x, window) - x * S0, _box_sum(v * y, window) - y * S0
    Sxx = _box_sum(v * x * x, window) - 2 * x * _box_sum(v * x, window) + x * x * S0
    Syy = _box_sum(v * y * y, window) - 2 * y * _box_sum(v * y, window) + y * y * S0
    Sxy = (_box_sum(v * x * y, window) - x * _box_sum(v * y, window) - y * _box_sum(v * x, window) + x * y * S0)
    SxP, SyP = _box_sum(P * x, window) - x * SP, _box_sum(P * y, window) - y * SP
    # Cramer's rule for a in [[S0 Sx Sy][Sx Sxx Sxy][Sy Sxy Syy]] [a b c] = [SP SxP SyP]
    det = S0 * (Sxx * Syy - Sxy * Sxy) - Sx * (Sx * Syy - Sxy * Sy) + Sy * (Sx * Sxy - Sxx * Sy)
    num = SP * (Sxx * Syy - Sxy * Sxy) - Sx * (SxP * Syy - Sxy * SyP) + Sy * (SxP * Sxy - Sxx * SyP)
    scale = S0 * (Sxx + Syy) ** 2 + 1e-12
    well = (S0 >= 3) & (det > 1e-6 * scale)
    plane = torch.where(well, num / torch.where(well, det, torch.ones_like(det)), mean)
    return torch.where(valid, plane, Phi.to(f64))


def coarse_cut(f_c: torch.Tensor, width=None) -> torch.Tensor:
    """unwrap.temporal.base_cut for per-sample coarse frequencies ``f_c`` (<= 1 period)."""
    from ..temporal import edge_fraction
    return torch.minimum(-torch.pi * (1.0 - f_c), -2 * torch.pi * f_c * edge_fraction(width))


def smoothed_prior(phase_low, phase_high, f_low, f_high, is_mf, valid, *, window: int = 15, fit: str = "plane",
                   width=None):
    """(prior (B,1,H,W) float64, usable (B,1,1,1) bool): the high frequency's prior with the coarse
    absolute phase filtered by :func:`smooth_phase`.

    Coarse phase: MF (``is_mf``) the unit phase; MW / NT the beat ``wrap(phi_h - phi_l)`` of
    ``f_h - f_l`` periods, absolute (``usable``) only for pairs at most one period apart.
    ARGUMENTS: wrapped phases (B,1,H,W) rad; frequencies and ``is_mf`` (B,1,1,1); valid (B,1,H,W).
    """
    from .._xp import wrap

    f64 = torch.float64
    phi_l, phi_h = phase_low.to(f64), phase_high.to(f64)
    f_l, f_h = f_low.to(f64), f_high.to(f64)
    beat = f_h - f_l
    usable = is_mf | (beat <= 1.0 + 1e-9)
    f_c = torch.where(is_mf, f_l, beat).clamp(max=1.0)
    cut = coarse_cut(f_c, width)
    coarse = torch.where(is_mf, phi_l, wrap(phi_h - phi_l))
    Phi = torch.remainder(coarse - cut, 2 * torch.pi) + cut
    Phi_s = smooth_phase(Phi, valid, window, fit)
    return (f_h / f_c * Phi_s - phi_h) / (2 * torch.pi), usable
