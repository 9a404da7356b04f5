"""numba kernel of :func:`unwrap.learned.fast_features.plane_filter` (``fit="plane"``; imported only
when numba is installed).

Two separable passes over a (H, W) phase, rows in parallel (``prange``), no temporaries:

1. per row, the valid pixels' sums over ``[x - r, x + r]`` of 1, dx, dx^2, phase and phase * dx
   (dx, dy: offsets from the box's centre pixel, so the coordinate moments are exact small
   integers instead of differences of large running sums);
2. per column, those sums over ``[y - r, y + r]`` (times 1, dy, dy^2 as needed) give the nine
   moments of the box, and the plane through the box's valid pixels is evaluated at its centre by
   Cramer's rule, with :func:`unwrap.learned.smoothing.smooth_phase`'s conditioning rule (fewer
   than 3 valid pixels or collinear ones: the box mean).

O(window) per pixel and pass (the box sums of the numpy path are O(1) but need nine float64
product planes and as many temporaries for the solve); compiled code is cached on disk.
"""
from __future__ import annotations

import numba as nb
import numpy as np

_JIT = dict(cache=True, error_model="numpy", nogil=True)


@nb.njit(**_JIT)
def _row_sums(Phi, valid, r, y, h):
    """Pass 1 on row ``y``: sums of 1, dx, dx^2, phase, phase * dx over the row's valid pixels."""
    W = Phi.shape[1]
    y = np.int64(y)
    for x in range(W):
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        a3 = 0.0
        a4 = 0.0
        for dx in range(max(-r, -x), min(r, W - 1 - x) + 1):
            if valid[y, x + dx]:
                p = Phi[y, x + dx]
                a0 += 1.0
                a1 += dx
                a2 += dx * dx
                a3 += p
                a4 += p * dx
        h[0, y, x] = a0
        h[1, y, x] = a1
        h[2, y, x] = a2
        h[3, y, x] = a3
        h[4, y, x] = a4


@nb.njit(**_JIT)
def _row_planes(Phi, valid, r, y, h, out):
    """Pass 2 on row ``y``: the box moments from pass 1's sums and the plane at each pixel."""
    H, W = Phi.shape
    y = np.int64(y)                  # a prange index may arrive unsigned: -y must be negative
    for x in range(W):
        if not valid[y, x]:
            out[y, x] = Phi[y, x]
            continue
        S0 = 0.0
        Sx = 0.0
        Sy = 0.0
        Sxx = 0.0
        Syy = 0.0
        Sxy = 0.0
        SP = 0.0
        SxP = 0.0
        SyP = 0.0
        for dy in range(max(-r, -y), min(r, H - 1 - y) + 1):
            h0 = h[0, y + dy, x]
            h1 = h[1, y + dy, x]
            h3 = h[3, y + dy, x]
            S0 += h0
            Sx += h1
            Sy += h0 * dy
            Sxx += h[2, y + dy, x]
            Syy += h0 * dy * dy
            Sxy += h1 * dy
            SP += h3
            SxP += h[4, y + dy, x]
            SyP += h3 * dy
        det = S0 * (Sxx * Syy - Sxy * Sxy) - Sx * (Sx * Syy - Sxy * Sy) + Sy * (Sx * Sxy - Sxx * Sy)
        scale = S0 * (Sxx + Syy) ** 2 + 1e-12
        if S0 >= 3 and det > 1e-6 * scale:
            num = SP * (Sxx * Syy - Sxy * Sxy) - Sx * (SxP * Syy - Sxy * SyP) + Sy * (SxP * Sxy - Sxx * SyP)
            out[y, x] = num / det
        else:
            out[y, x] = SP / max(S0, 1.0)


@nb.njit(parallel=True, **_JIT)
def _pass1(Phi, valid, r, h):
    for y in nb.prange(Phi.shape[0]):
        _row_sums(Phi, valid, r, y, h)


@nb.njit(parallel=True, **_JIT)
def _pass2(Phi, valid, r, h, out):
    for y in nb.prange(Phi.shape[0]):
        _row_planes(Phi, valid, r, y, h, out)


def plane_filter_kernel(Phi, valid, r):
    """Plane-filtered ``Phi`` (H, W) float64 over ``valid`` (H, W) bool in (2 r + 1) boxes; invalid
    pixels keep ``Phi``. (Two compiled functions: numba would fuse two ``prange`` loops of one
    function into one, and pass 2 reads the rows around its own that pass 1 writes.)"""
    H, W = Phi.shape
    h = np.empty((5, H, W))
    _pass1(Phi, valid, r, h)
    out = np.empty((H, W))
    _pass2(Phi, valid, r, h, out)
    return out
