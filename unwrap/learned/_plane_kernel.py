"""numba kernel of :func:`unwrap.learned.fast_features.plane_filter` (``fit="plane"``; imported only
when numba is installed).

Two separable passes over a (H, W) phase, O(1) work per pixel and pass (sliding box sums), no
per-pixel Python:

1. along each row, the valid pixels' sums over ``[x - r, x + r]`` of 1, dx, dx^2, phase and
   phase * dx (dx, dy: offsets from the box's centre pixel);
2. down each column, those sums over ``[y - r, y + r]`` (times 1, dy, dy^2 as needed) give the
   nine moments of the box, and the plane through the box's valid pixels is evaluated at its centre
   by Cramer's rule, with :func:`unwrap.learned.smoothing.smooth_phase`'s conditioning rule (fewer
   than 3 valid pixels or collinear ones: the box mean).

Sliding, not cumulative sums: moving the centre by one pixel updates the centred moments in place
(``sum dx' h = sum dx h - sum h``, ``sum dx'^2 h = sum dx^2 h - 2 sum dx h + sum h`` over the old
box, then the leaving line is removed and the entering one added), so every moment stays about its
own box centre. That is why float64 suffices and float32 would not: a cumulative sum of phase * x
grows to ~1e6 rad px over a 640 px row and the centred moment is its difference with x * sum phase,
losing 6 of float32's 7 digits (and ~1e-10 in float64); centred, the magnitudes stay those of one
box (~1e3) and the coordinate moments are exact small integers. The phase moments still collect
one rounding per step, so each run of :data:`BLOCK` outputs restarts from an exact sum over its
first box: the drift is bounded by ``BLOCK`` roundings (measured: within 2.5e-13 rad of the
previous kernel's direct sums on the 640 x 480 speed scene). Blocks are also the parallel unit
(``prange``); compiled code is cached on disk.
"""
from __future__ import annotations

import numba as nb
import numpy as np

_JIT = dict(cache=True, error_model="numpy", nogil=True)
#: Outputs per sliding run (restart from an exact box sum after this many steps).
BLOCK = 64


@nb.njit(**_JIT)
def _row_block(Phi, valid, r, y, x0, x1, h):
    """Pass 1 on row ``y``, outputs x0..x1-1: sums of 1, dx, dx^2, phase, phase * dx."""
    W = Phi.shape[1]
    a0 = 0.0
    a1 = 0.0
    a2 = 0.0
    a3 = 0.0
    a4 = 0.0
    for xx in range(max(x0 - r, 0), min(x0 + r, W - 1) + 1):      # the exact first box
        if valid[y, xx]:
            d = xx - x0
            p = Phi[y, xx]
            a0 += 1.0
            a1 += d
            a2 += d * d
            a3 += p
            a4 += p * d
    x = x0
    while True:
        h[0, y, x] = a0
        h[1, y, x] = a1
        h[2, y, x] = a2
        h[3, y, x] = a3
        h[4, y, x] = a4
        x += 1
        if x >= x1:
            break
        # re-centre at x (offsets decrease by 1), then drop x - r - 1 (offset -r - 1), add x + r (offset r)
        a2 = a2 - 2.0 * a1 + a0
        a1 = a1 - a0
        a4 = a4 - a3
        xo = x - r - 1
        if xo >= 0 and valid[y, xo]:
            p = Phi[y, xo]
            a0 -= 1.0
            a1 += r + 1
            a2 -= (r + 1) * (r + 1)
            a3 -= p
            a4 += p * (r + 1)
        xi = x + r
        if xi < W and valid[y, xi]:
            p = Phi[y, xi]
            a0 += 1.0
            a1 += r
            a2 += r * r
            a3 += p
            a4 += p * r


@nb.njit(**_JIT)
def _solve(Phi, valid, y, S, out):
    """The plane at each pixel of row ``y`` from the box moments ``S`` (9, W)."""
    W = Phi.shape[1]
    for x in range(W):
        if not valid[y, x]:
            out[y, x] = Phi[y, x]
            continue
        S0 = S[0, x]
        Sx = S[1, x]
        Sy = S[2, x]
        Sxx = S[3, x]
        Syy = S[4, x]
        Sxy = S[5, x]
        SP = S[6, x]
        SxP = S[7, x]
        SyP = S[8, x]
        det = S0 * (Sxx * Syy - Sxy * Sxy) - Sx * (Sx * Syy - Sxy * Sy) + Sy * (Sx * Sxy - Sxx * Sy)
        scale = S0 * (Sxx + Syy) ** 2 + 1e-12
        if S0 >= 3 and det > 1e-6 * scale:
            num = SP * (Sxx * Syy - Sxy * Sxy) - Sx * (SxP * Syy - Sxy * SyP) + Sy * (SxP * Sxy - Sxx * SyP)
            out[y, x] = num / det
        else:
            out[y, x] = SP / max(S0, 1.0)


@nb.njit(**_JIT)
def _add_row(S, h, yy, d, sign):
    """S += sign * (the moments of pass-1 row ``yy`` at vertical offset ``d``)."""
    W = S.shape[1]
    for x in range(W):
        h0 = h[0, yy, x]
        h1 = h[1, yy, x]
        h3 = h[3, yy, x]
        S[0, x] += sign * h0
        S[1, x] += sign * h1
        S[2, x] += sign * (h0 * d)
        S[3, x] += sign * h[2, yy, x]
        S[4, x] += sign * (h0 * (d * d))
        S[5, x] += sign * (h1 * d)
        S[6, x] += sign * h3
        S[7, x] += sign * h[4, yy, x]
        S[8, x] += sign * (h3 * d)


@nb.njit(**_JIT)
def _col_block(Phi, valid, r, y0, y1, h, out):
    """Pass 2 on rows y0..y1-1: slide the box moments down, a row of pixels at a time."""
    H, W = Phi.shape
    S = np.zeros((9, W))
    for yy in range(max(y0 - r, 0), min(y0 + r, H - 1) + 1):     # the exact first box
        _add_row(S, h, yy, float(yy - y0), 1.0)
    y = y0
    while True:
        _solve(Phi, valid, y, S, out)
        y += 1
        if y >= y1:
            break
        for x in range(W):                                       # re-centre at y: dy' = dy - 1
            S[4, x] = S[4, x] - 2.0 * S[2, x] + S[0, x]
            S[2, x] = S[2, x] - S[0, x]
            S[5, x] = S[5, x] - S[1, x]
            S[8, x] = S[8, x] - S[6, x]
        if y - r - 1 >= 0:
            _add_row(S, h, y - r - 1, float(-r - 1), -1.0)
        if y + r < H:
            _add_row(S, h, y + r, float(r), 1.0)


@nb.njit(parallel=True, **_JIT)
def _pass1(Phi, valid, r, h, block):
    H, W = Phi.shape
    nb_x = (W + block - 1) // block
    for k in nb.prange(H * nb_x):
        y = np.int64(k) // nb_x
        x0 = (np.int64(k) % nb_x) * block
        _row_block(Phi, valid, r, y, x0, min(x0 + block, W), h)


@nb.njit(parallel=True, **_JIT)
def _pass2(Phi, valid, r, h, out, block):
    H = Phi.shape[0]
    for k in nb.prange((H + block - 1) // block):
        y0 = np.int64(k) * block
        _col_block(Phi, valid, r, y0, min(y0 + block, H), h, out)


def plane_filter_kernel(Phi, valid, r):
    """Plane-filtered ``Phi`` (H, W) float64 over ``valid`` (H, W) bool in (2 r + 1) boxes; invalid
    pixels keep ``Phi``. (Two compiled functions: numba would fuse two ``prange`` loops of one
    function into one, and pass 2 reads the rows around its own that pass 1 writes.)"""
    H, W = Phi.shape
    h = np.empty((5, H, W))
    _pass1(Phi, valid, int(r), h, BLOCK)
    out = np.empty((H, W))
    _pass2(Phi, valid, int(r), h, out, BLOCK)
    return out
