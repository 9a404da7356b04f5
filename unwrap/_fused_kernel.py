"""numba kernel of :func:`unwrap.fused_mf.mf_unwrap_stacks` (imported only when numba is installed).

One pass over the frames: for each block of pixels and each frequency, the float64 sums
``[A, C, S] = P @ I`` of the least-squares fit (frames in order n = 0..N-1), then per pixel
``B = sqrt(C^2 + S^2)``, the masks and the wrapped phase ``atan2(S, C)`` (kept in a block-sized
scratch array), then the MF chain of :func:`unwrap.temporal.mf_unwrap` (base phase, eq. 7 steps,
final masks). Blocks run in parallel (``prange``); compiled code is cached on disk
(``cache=True``), so only the first use on a machine pays the compile time.

``error_model="numpy"`` (IEEE division, no ZeroDivisionError checks) and branch-free arithmetic
let LLVM vectorise the per-pixel loops, the arctangent included.

Arctangent: ``_atan2`` reduces ``atan2(y, x)`` to ``atan(t)``, ``t = min(|x|,|y|)/max(|x|,|y|)``
in [0, 1], uses ``atan(t) = pi/4 + atan((t - 1)/(t + 1))`` above t = 0.66 and the rational
approximation ``atan(u) = u + u z P(z)/Q(z)``, ``z = u^2``, of the Cephes Math Library
(S. L. Moshier, ``atan.c``, coefficients below; relative error ~1e-16 on |u| <= 0.66), then
the octant and quadrant from the signs (IEEE signed zeros as C's atan2). Measured against
``numpy.arctan2``: at most 4.5e-16 rad (2 ulp) over 1e6 random and all signed-zero points
(tests/test_unwrap_fused.py).
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

# Cephes atan.c rational approximation, atan(u) = u + u*z*P(z)/Q(z) with z = u^2, |u| <= 0.66
_P0, _P1, _P2, _P3, _P4 = (-8.750608600031904122785e-1, -1.615753718733365076637e1,
                           -7.500855792314704667340e1, -1.228866684490136173410e2,
                           -6.485021904942025371773e1)
_Q0, _Q1, _Q2, _Q3, _Q4 = (2.485846490142306297962e1, 1.650270098316988542046e2,
                           4.328810604912902668951e2, 4.853903996359136964868e2,
                           1.945506571482613964425e2)
_PI = math.pi
_PI_2 = 0.5 * math.pi
_PI_4 = 0.25 * math.pi
_PI_4_LO = 3.061616997868383e-17  # pi/4 - float(pi/4)
_TWO_PI = 2.0 * math.pi
_JIT = dict(cache=True, error_model="numpy", nogil=True)


@nb.njit(inline="always", **_JIT)
def _atan2(y, x):
    """atan2(y, x) in [-pi, pi] (float64), branch-free so that loops calling it vectorise."""
    ax = abs(x)
    ay = abs(y)
    mx = max(ax, ay)
    mn = min(ax, ay)
    t = mn / (mx if mx > 0.0 else 1.0)
    big = t > 0.66
    ub = (t - 1.0) / (t + 1.0)
    u = ub if big else t
    z = u * u
    p = (((_P0 * z + _P1) * z + _P2) * z + _P3) * z + _P4
    q = ((((z + _Q0) * z + _Q1) * z + _Q2) * z + _Q3) * z + _Q4
    r = u + u * (z * p / q)
    rb = _PI_4 + (r + _PI_4_LO)
    r = rb if big else r
    rs = _PI_2 - r
    r = rs if ay > ax else r
    rn = _PI - r
    r = rn if math.copysign(1.0, x) < 0.0 else r
    return math.copysign(r, y)


@nb.njit(**_JIT)
def atan2_array(y, x, out):
    """``out[i] = _atan2(y[i], x[i])`` for 1-D float64 arrays (for tests and the benchmark)."""
    for i in range(y.size):
        out[i] = _atan2(y[i], x[i])


_BLOCK = 2048  # pixels per block: the block's sums and phases stay in L1/L2


@nb.njit(inline="always", **_JIT)
def _accumulate(st, s0, m, P, c0, sa, sc, ss, imax, imin):
    """Sums ``sa/sc/ss[j] = sum_n P[0/1/2, c0 + n] * st[n, s0 + j]`` (float64, n in order) and
    the per-pixel max/min frame value over the N frames of one stack, pixels s0 .. s0+m-1.

    Four frames per pass over the block (same left-to-right sum as one frame per pass, a
    quarter of the accumulator loads and stores)."""
    N = st.shape[0]
    r = st[0, s0:s0 + m]
    for j in range(m):
        sa[j] = 0.0
        sc[j] = 0.0
        ss[j] = 0.0
        imax[j] = r[j]
        imin[j] = r[j]
    n = 0
    while n + 4 <= N:
        r0 = st[n, s0:s0 + m]
        r1 = st[n + 1, s0:s0 + m]
        r2 = st[n + 2, s0:s0 + m]
        r3 = st[n + 3, s0:s0 + m]
        c = c0 + n
        a0, a1, a2, a3 = P[0, c], P[0, c + 1], P[0, c + 2], P[0, c + 3]
        b0, b1, b2, b3 = P[1, c], P[1, c + 1], P[1, c + 2], P[1, c + 3]
        e0, e1, e2, e3 = P[2, c], P[2, c + 1], P[2, c + 2], P[2, c + 3]
        for j in range(m):
            v0 = r0[j]
            v1 = r1[j]
            v2 = r2[j]
            v3 = r3[j]
            x0 = np.float64(v0)
            x1 = np.float64(v1)
            x2 = np.float64(v2)
            x3 = np.float64(v3)
            sa[j] = (((sa[j] + a0 * x0) + a1 * x1) + a2 * x2) + a3 * x3
            sc[j] = (((sc[j] + b0 * x0) + b1 * x1) + b2 * x2) + b3 * x3
            ss[j] = (((ss[j] + e0 * x0) + e1 * x1) + e2 * x2) + e3 * x3
            imax[j] = max(imax[j], max(max(v0, v1), max(v2, v3)))
            imin[j] = min(imin[j], min(min(v0, v1), min(v2, v3)))
        n += 4
    while n < N:
        r0 = st[n, s0:s0 + m]
        c = c0 + n
        a0, b0, e0 = P[0, c], P[1, c], P[2, c]
        for j in range(m):
            v0 = r0[j]
            x0 = np.float64(v0)
            sa[j] += a0 * x0
            sc[j] += b0 * x0
            ss[j] += e0 * x0
            imax[j] = max(imax[j], v0)
            imin[j] = min(imin[j], v0)
        n += 1


@nb.njit(parallel=True, **_JIT)
def mf_kernel(stacks, P, offsets, ratios, cut, sat, lo, hi, min_mod, kmax,
              phase, order, valid, prior, A_out, B_out, lev_prior, lev_k):
    """Fused wrapped phase (every stack) + MF unwrapping.

    stacks: tuple of F (N_f, n_pix) uint8/uint16 C-contiguous arrays; P: (3, sum N_f) float64
    least-squares weights, stack f's columns at offsets[f]:offsets[f+1]; ratios[i] =
    f_i / f_{i-1} (ratios[0] unused); cut: base-phase cut (rad); sat: saturation level (inf: none);
    lo, hi: valid range (+-inf: none); min_mod: low-modulation threshold; kmax: largest order.
    Outputs (n_pix,): phase, order, valid, prior, A_out, B_out (highest frequency);
    lev_prior, lev_k: (F-1, n_pix) or (0, 0) when not wanted.
    """
    F = len(stacks)
    n_pix = phase.size
    want_levels = lev_prior.shape[0] > 0
    n_blocks = (n_pix + _BLOCK - 1) // _BLOCK
    for b in nb.prange(n_blocks):
        s0 = b * _BLOCK
        m = min(_BLOCK, n_pix - s0)
        sa = np.empty(m, np.float64)
        sc = np.empty(m, np.float64)
        ss = np.empty(m, np.float64)
        bmod = np.empty(m, np.float64)
        phis = np.empty((F, m), np.float64)
        ok = np.ones(m, np.bool_)
        for f in range(F):
            st = stacks[f]
            imax = np.empty(m, st.dtype)
            imin = np.empty(m, st.dtype)
            _accumulate(st, s0, m, P, offsets[f], sa, sc, ss, imax, imin)
            ph_f = phis[f]
            for j in range(m):
                # masks and phase exactly as unwrap.phase_shift._wrapped_phase_numpy
                a = sa[j]
                cc = sc[j]
                sn = ss[j]
                Bm = math.sqrt(cc * cc + sn * sn)
                defined = (Bm > 1e-9 * abs(a)) & (Bm > 0.0)
                oor = (np.float64(imin[j]) < lo) | (np.float64(imax[j]) > hi)
                saturated = np.float64(imax[j]) >= sat
                good = defined & ~(Bm < min_mod) & ~oor & ~saturated
                ph = _atan2(sn, cc)
                ph_f[j] = ph if good else np.nan
                ok[j] = ok[j] & good
                bmod[j] = Bm if (defined & ~oor) else 0.0
        for j in range(m):
            A_out[s0 + j] = sa[j]
            B_out[s0 + j] = bmod[j]
        # MF chain of unwrap.temporal.mf_unwrap, one frequency step at a time over the block
        Phi_s = np.empty(m, np.float64)
        pr_s = np.full(m, np.nan)
        k_s = np.full(m, np.nan)
        p0 = phis[0]
        for j in range(m):
            # base phase (unwrap.temporal.base_phase): remainder(phi - c, 2 pi) + c, |phi - c| < 2 pi
            d = p0[j] - cut
            Phi_s[j] = (d + _TWO_PI if d < 0.0 else d) + cut
        for i in range(1, F):
            ratio = ratios[i]
            p_i = phis[i]
            for j in range(m):
                phi = p_i[j]
                pr = (ratio * Phi_s[j] - phi) / _TWO_PI  # eq. 7, unwrap.temporal.refine
                k = np.rint(pr)  # half to even, as numpy.round
                Phi_s[j] = phi + _TWO_PI * k
                pr_s[j] = pr
                k_s[j] = k
            if want_levels:
                for j in range(m):
                    lev_prior[i - 1, s0 + j] = pr_s[j]
                    lev_k[i - 1, s0 + j] = k_s[j]
        for j in range(m):
            # unwrap.temporal._finish
            k = k_s[j]
            g = ok[j] & (k >= 0.0) & (k <= kmax)
            phase[s0 + j] = Phi_s[j] if g else np.nan
            order[s0 + j] = np.int32(k if g else -1.0)
            valid[s0 + j] = g
            prior[s0 + j] = pr_s[j] if ok[j] else np.nan
