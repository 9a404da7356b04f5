"""The plane-fit kernel of :mod:`unwrap.learned._plane_kernel` in numpy, bit for bit.

Why: a process that decodes one capture pays ~0.8-1 s of CPU and ~120 MB of resident memory to
import numba and load the compiled kernel from its cache (docs/speed.md, session 9), for a
kernel that then runs in ~10 ms a box. :mod:`unwrap.learned._plane_c` runs it in C where a C
compiler is at hand; this module, the fallback, runs the same two sliding passes with numpy,
vectorised across the independent runs instead of across pixels, every box size at once: pass 1
advances every (box, row, block of :data:`BLOCK` columns) run one column per step, pass 2 every
(box, block of :data:`BLOCK` rows) run one row per step over the whole row width. Every float64
operation is the kernel's, on the same operands, in the same order; a pixel the kernel skips
enters as an exact zero, which leaves the sums' bits unchanged (:func:`_pass1`). numba compiles
without fast-math (no reassociation, no fused multiply-adds), so the outputs are bitwise the
kernel's (tests/test_plane_numpy.py: synthetic phases with holes, NaN and -0.0, and a real capture).

Shapes: ``Phi`` (H, W) float64 rad, ``valid`` (H, W) bool, ``radii`` half boxes (px); out: one
(H, W) float64 per radius. Cost: ~``BLOCK + 2 max(radii)`` numpy steps per pass on arrays of
~H * W * len(radii) / BLOCK elements: ~0.1 s of CPU a box at 900 x 700 (load ~5), whether the boxes
run together or one by one (``fast_features`` runs them one by one: half the transient memory).
"""
from __future__ import annotations

import numpy as np

#: Outputs per sliding run: :data:`unwrap.learned._plane_kernel.BLOCK` (numba-free here; a test holds them equal).
BLOCK = 64


def _pass1(Phi, valid, radii, block):
    """(nr, 5, H, W) row moments about each pixel, per radius r: sums over ``[x - r, x + r]`` of
    the valid pixels' 1, dx, dx^2, phase, phase * dx (``_plane_kernel._row_block`` on every run at
    once). Runs along the columns of the transposed frame (rows of ``PhiT``: contiguous gathers).

    A pixel the kernel skips (invalid, outside the frame, or beyond a smaller box's first box) is
    added here as a zero: its weight ``take`` is 0.0 and its phase is taken as 0.0, so every term
    is +-0.0, and adding or subtracting a zero leaves any sum that is not -0.0 unchanged, bit for
    bit. No sum here is ever -0.0: they start at +0.0, and under round-to-nearest a sum or
    difference is -0.0 only when its first operand already is (x + y = -0.0 needs x = y = -0.0;
    x - y = -0.0 needs x = -0.0, y = +0.0)."""
    H, W = Phi.shape
    takeT = np.ascontiguousarray(valid.T, dtype=np.float64)            # 1.0 valid, 0.0 not
    PhiT = np.where(takeT > 0, np.ascontiguousarray(Phi.T), 0.0)       # NaN of invalid pixels -> 0
    nr, nbx = len(radii), (W + block - 1) // block
    r = np.asarray(radii)[:, None]                                       # (nr, 1)
    x0 = np.arange(nbx) * block                       # each run's first output column
    x1 = np.minimum(x0 + block, W)
    hT = np.empty((5, W, nr, H))
    a0, a1, a2, a3, a4 = (np.zeros((nr, nbx, H)) for _ in range(5))
    tmp = np.empty((nr, nbx, H))

    def update(x, inside, op, d):
        """``op`` (add / subtract) column ``x`` (nr, nbx) of each run at its offset ``d`` (nr, 1,
        1; the kernel's: the entering column at +r, the leaving one at -r - 1, whose signed terms
        it adds), where ``inside``"""
        xc = np.clip(x, 0, W - 1)
        take, p = takeT[xc], PhiT[xc]
        if not inside.all():
            take, p = take * inside[..., None], p * inside[..., None]
        sd = d if op is np.add else -d
        op(a0, take, out=a0)                                          # a0 +- 1.0
        np.add(a1, np.multiply(take, sd, out=tmp), out=a1)            # a1 += d | a1 += r + 1
        op(a2, np.multiply(take, d * d, out=tmp), out=a2)             # a2 +- d^2
        op(a3, p, out=a3)                                             # a3 +- phase
        np.add(a4, np.multiply(p, sd, out=tmp), out=a4)               # a4 += phase * d | phase * (r + 1)

    for d in range(-int(r.max()), int(r.max()) + 1):   # the exact first box, xx = x0 + d ascending
        xx = np.broadcast_to(x0 + d, (nr, nbx))
        update(xx, (xx >= 0) & (xx <= W - 1) & (abs(d) <= r), np.add, float(d))
    rf = r[..., None].astype(np.float64)
    for s in range(block):
        x = x0 + s
        live = x < x1                                  # runs that still have an output here
        for i, a in enumerate((a0, a1, a2, a3, a4)):
            hT[i][x[live]] = a[:, live].transpose(1, 0, 2)
        if s == block - 1:
            break
        x = x + 1
        np.multiply(a1, 2.0, out=tmp)                  # re-centre at x: a2 - 2 a1 + a0, a1 - a0, a4 - a3
        np.subtract(a2, tmp, out=a2)
        np.add(a2, a0, out=a2)
        np.subtract(a1, a0, out=a1)
        np.subtract(a4, a3, out=a4)
        update(x - r - 1, x - r - 1 >= 0, np.subtract, -(rf + 1.0))
        update(x + r, x + r < W, np.add, rf)
    return np.ascontiguousarray(hT.transpose(2, 0, 3, 1))


def _add_row(S, h, yy, d, sign, take):
    """``_plane_kernel._add_row`` for each run: S[:, b, k] += sign * (moments of row ``yy[b, k]``
    of box b at offset ``d[b, k]``) where ``take[b, k]``; ``S`` (9, nr, K, W), ``h`` (nr, 5, H,
    W), ``yy`` / ``d`` / ``take`` (nr, K). ``x + (-1.0 * t)`` is ``x - t`` exactly, so sign -1
    subtracts."""
    yc = np.clip(yy, 0, h.shape[2] - 1)
    b = np.arange(h.shape[0])[:, None]
    h0, h1, h2, h3, h4 = (h[b, i, yc] for i in range(5))
    d = np.asarray(d, dtype=np.float64)[..., None]
    op = np.add if sign > 0 else np.subtract
    every = bool(take.all())
    t = take[..., None]
    for i, term in ((0, h0), (1, h1), (2, h0 * d), (3, h2), (4, h0 * (d * d)), (5, h1 * d), (6, h3), (7, h4),
                    (8, h3 * d)):
        if every:
            op(S[i], term, out=S[i])
        else:
            S[i] = np.where(t, op(S[i], term), S[i])


def _solve(Phi_rows, valid_rows, S):
    """``_plane_kernel._solve`` on the rows of every run: the plane at each pixel from ``S`` (the
    kernel's expressions; ``Sxx Syy - Sxy^2``, which it evaluates twice, once here)."""
    S0, Sx, Sy, Sxx, Syy, Sxy, SP, SxP, SyP = S
    m = Sxx * Syy - Sxy * Sxy
    det = S0 * m - Sx * (Sx * Syy - Sxy * Sy) + Sy * (Sx * Sxy - Sxx * Sy)
    scale = S0 * (Sxx + Syy) ** 2 + 1e-12
    well = (S0 >= 3) & (det > 1e-6 * scale)
    num = SP * m - Sx * (SxP * Syy - Sxy * SyP) + Sy * (SxP * Sxy - Sxx * SyP)
    with np.errstate(divide="ignore", invalid="ignore"):
        np.divide(num, det, out=num)
    np.putmask(num, ~well, SP / np.maximum(S0, 1.0))
    np.copyto(num, Phi_rows, where=~valid_rows)
    return num


def _pass2(Phi, valid, radii, h, block):
    """Slide the box moments down every (box, block of rows) at once (``_plane_kernel._col_block``)."""
    H, W = Phi.shape
    nr, nby = len(radii), (H + block - 1) // block
    r = np.asarray(radii)[:, None]                    # (nr, 1)
    y0 = np.broadcast_to(np.arange(nby) * block, (nr, nby))
    y1 = np.minimum(np.arange(nby) * block + block, H)
    out = np.empty((nr, H, W))
    S = np.zeros((9, nr, nby, W))
    for d in range(-int(r.max()), int(r.max()) + 1):   # the exact first box, yy = y0 + d ascending
        yy = y0 + d
        _add_row(S, h, yy, yy - y0, 1.0, (yy >= 0) & (yy <= H - 1) & (abs(d) <= r))
    down, up = np.broadcast_to(-r - 1.0, (nr, nby)), np.broadcast_to(r.astype(np.float64), (nr, nby))
    for s in range(block):
        y = np.arange(nby) * block + s
        live = y < y1                                  # the same blocks of rows for every box
        rows = y[live]
        out[:, rows] = _solve(Phi[rows], valid[rows], S[:, :, live])
        if s == block - 1:
            break
        y = y0 + s + 1
        S[4] = S[4] - 2.0 * S[2] + S[0]               # re-centre at y: dy' = dy - 1
        S[2] = S[2] - S[0]
        S[5] = S[5] - S[1]
        S[8] = S[8] - S[6]
        _add_row(S, h, y - r - 1, down, -1.0, y - r - 1 >= 0)
        _add_row(S, h, y + r, up, 1.0, y + r < H)
    return out


def plane_filter_numpy(Phi, valid, radii, block: int = BLOCK) -> list:
    """Plane-filtered ``Phi`` (H, W) float64 over ``valid`` (H, W) bool in (2 r + 1) boxes, one
    (H, W) map per r of ``radii`` (an int: one map); invalid pixels keep ``Phi``: each
    :func:`unwrap.learned._plane_kernel.plane_filter_kernel` ``(Phi, valid, r)``, bitwise."""
    one = np.ndim(radii) == 0
    radii = tuple(int(r) for r in np.atleast_1d(radii))
    Phi = np.ascontiguousarray(Phi, dtype=np.float64)
    valid = np.ascontiguousarray(valid, dtype=bool)
    out = _pass2(Phi, valid, radii, _pass1(Phi, valid, radii, int(block)), int(block))
    return out[0] if one else list(out)
