"""The plane-fit kernel of :mod:`unwrap.learned._plane_kernel` in numpy, bit for bit.

Why: a process that decodes one capture pays ~0.8-1 s of CPU and ~120 MB of resident memory to
import numba and load the compiled kernel from its cache (docs/speed.md, session 9), for a
kernel that then runs in ~10 ms a box. This module runs the same two sliding passes with numpy,
vectorised across the independent runs instead of across pixels: pass 1 advances every
(row, block of :data:`BLOCK` columns) run one column per step, pass 2 every block of
:data:`BLOCK` rows one row per step, each over the whole row width. Every float64 operation is
the kernel's, on the same operands, in the same order (a skipped update is a ``where`` that keeps
the old value, never an added zero), so the outputs are bitwise the kernel's (numba compiles
without fast-math: no reassociation, no fused multiply-adds; tests/test_plane_numpy.py compares
them on synthetic phases with holes and on a real capture).

Shapes: ``Phi`` (H, W) float64 rad, ``valid`` (H, W) bool, ``r`` half box (px); out (H, W)
float64. Cost: ~``BLOCK + 2 r`` numpy steps per pass on arrays of H * W / BLOCK (pass 1) and
W * H / BLOCK (pass 2) elements: ~40-60 ms a box at 900 x 700 on one core.
"""
from __future__ import annotations

import numpy as np

#: Outputs per sliding run: :data:`unwrap.learned._plane_kernel.BLOCK` (numba-free here; a test holds them equal).
BLOCK = 64


def _pass1(Phi, valid, r, block):
    """(5, H, W) row moments about each pixel: sums over ``[x - r, x + r]`` of the valid pixels'
    1, dx, dx^2, phase, phase * dx (``_plane_kernel._row_block`` on every run at once). Runs
    along the columns of the transposed frame (rows of ``PhiT``: contiguous gathers).

    A pixel the kernel skips (invalid, or outside the frame) is added here as a zero: its weight
    ``take`` is 0.0 and its phase is taken as 0.0, so every term is +-0.0, and adding or
    subtracting a zero leaves any sum that is not -0.0 unchanged, bit for bit. No sum here is ever
    -0.0: they start at +0.0, and under round-to-nearest a sum or difference is -0.0 only when its
    first operand already is (x + y = -0.0 needs x = y = -0.0; x - y = -0.0 needs x = -0.0, y = +0.0)."""
    H, W = Phi.shape
    takeT = np.ascontiguousarray(valid.T, dtype=np.float64)            # 1.0 valid, 0.0 not
    PhiT = np.where(takeT > 0, np.ascontiguousarray(Phi.T), 0.0)       # NaN of invalid pixels -> 0
    nbx = (W + block - 1) // block
    x0 = np.arange(nbx) * block                       # each run's first output column
    x1 = np.minimum(x0 + block, W)
    hT = np.empty((5, W, H))
    a0, a1, a2, a3, a4 = (np.zeros((nbx, H)) for _ in range(5))
    tmp = np.empty((nbx, H))

    def update(x, inside, op, d):
        """``op`` (add / subtract) column ``x`` of each run, its offset ``d`` (the kernel's: the
        entering column at +r, the leaving one at -r - 1, whose signed terms it adds)"""
        xc = np.clip(x, 0, W - 1)
        take, p = takeT[xc], PhiT[xc]
        if not inside.all():
            take, p = take * inside[:, None], p * inside[:, None]
        op(a0, take, out=a0)                                          # a0 +- 1.0
        np.add(a1, np.multiply(take, d if op is np.add else -d, out=tmp), out=a1)   # a1 += d | a1 += r + 1
        op(a2, np.multiply(take, d * d, out=tmp), out=a2)             # a2 +- d^2
        op(a3, p, out=a3)                                             # a3 +- phase
        np.add(a4, np.multiply(p, d if op is np.add else -d, out=tmp), out=a4)       # a4 += phase * d | (r + 1)

    for d in range(-r, r + 1):                        # the exact first box, xx = x0 + d ascending
        xx = x0 + d
        update(xx, (xx >= 0) & (xx <= W - 1), np.add, d)
    for s in range(block):
        x = x0 + s
        live = x < x1                                  # runs that still have an output here
        full = bool(live.all())
        for i, a in enumerate((a0, a1, a2, a3, a4)):
            if full:
                hT[i][x] = a
            else:
                hT[i][x[live]] = a[live]
        if s == block - 1:
            break
        x = x + 1
        np.multiply(a1, 2.0, out=tmp)                  # re-centre at x: a2 - 2 a1 + a0, a1 - a0, a4 - a3
        np.subtract(a2, tmp, out=a2)
        np.add(a2, a0, out=a2)
        np.subtract(a1, a0, out=a1)
        np.subtract(a4, a3, out=a4)
        update(x - r - 1, x - r - 1 >= 0, np.subtract, -(r + 1))
        update(x + r, x + r < W, np.add, r)
    return np.ascontiguousarray(hT.transpose(0, 2, 1))


def _add_row(S, h, yy, d, sign, take):
    """``_plane_kernel._add_row`` for each run: S[:, k] += sign * (moments of row ``yy[k]`` at
    offset ``d[k]``) where ``take[k]``; ``S`` (9, K, W), ``yy`` / ``d`` (K,). ``x + (-1.0 * t)``
    is ``x - t`` exactly, so sign -1 subtracts."""
    yc = np.clip(yy, 0, h.shape[1] - 1)
    h0, h1, h2, h3, h4 = (h[i][yc] for i in range(5))
    d = np.asarray(d, dtype=np.float64)[:, None]
    op = np.add if sign > 0 else np.subtract
    every = bool(take.all())
    t = take[:, None]
    for i, term in ((0, h0), (1, h1), (2, h0 * d), (3, h2), (4, h0 * (d * d)), (5, h1 * d), (6, h3), (7, h4),
                    (8, h3 * d)):
        if every:
            op(S[i], term, out=S[i])
        else:
            S[i] = np.where(t, op(S[i], term), S[i])


def _solve(Phi_rows, valid_rows, S):
    """``_plane_kernel._solve`` on the rows of every run: the plane at each pixel from ``S``."""
    S0, Sx, Sy, Sxx, Syy, Sxy, SP, SxP, SyP = S
    det = S0 * (Sxx * Syy - Sxy * Sxy) - Sx * (Sx * Syy - Sxy * Sy) + Sy * (Sx * Sxy - Sxx * Sy)
    scale = S0 * (Sxx + Syy) ** 2 + 1e-12
    num = SP * (Sxx * Syy - Sxy * Sxy) - Sx * (SxP * Syy - Sxy * SyP) + Sy * (SxP * Sxy - Sxx * SyP)
    well = (S0 >= 3) & (det > 1e-6 * scale)
    with np.errstate(divide="ignore", invalid="ignore"):
        plane = np.where(well, num / np.where(well, det, 1.0), SP / np.maximum(S0, 1.0))
    return np.where(valid_rows, plane, Phi_rows)


def _pass2(Phi, valid, r, h, block):
    """Slide the box moments down every block of rows at once (``_plane_kernel._col_block``)."""
    H, W = Phi.shape
    nby = (H + block - 1) // block
    y0 = np.arange(nby) * block
    y1 = np.minimum(y0 + block, H)
    out = np.empty((H, W))
    S = np.zeros((9, nby, W))
    for d in range(-r, r + 1):                        # the exact first box, yy = y0 + d ascending
        yy = y0 + d
        _add_row(S, h, yy, yy - y0, 1.0, (yy >= 0) & (yy <= H - 1))
    for s in range(block):
        y = y0 + s
        live = y < y1
        rows = y[live]
        out[rows] = _solve(Phi[rows], valid[rows], S[:, live])
        if s == block - 1:
            break
        y = y + 1
        S[4] = S[4] - 2.0 * S[2] + S[0]               # re-centre at y: dy' = dy - 1
        S[2] = S[2] - S[0]
        S[5] = S[5] - S[1]
        S[8] = S[8] - S[6]
        _add_row(S, h, y - r - 1, np.full(nby, -r - 1.0), -1.0, y - r - 1 >= 0)
        _add_row(S, h, y + r, np.full(nby, float(r)), 1.0, y + r < H)
    return out


def plane_filter_numpy(Phi, valid, r, block: int = BLOCK):
    """Plane-filtered ``Phi`` (H, W) float64 over ``valid`` (H, W) bool in (2 r + 1) boxes; invalid
    pixels keep ``Phi``: :func:`unwrap.learned._plane_kernel.plane_filter_kernel`'s result, bitwise."""
    Phi = np.ascontiguousarray(Phi, dtype=np.float64)
    valid = np.ascontiguousarray(valid, dtype=bool)
    r = int(r)
    return _pass2(Phi, valid, r, _pass1(Phi, valid, r, int(block)), int(block))
