"""The fused MF kernel (:func:`unwrap._fused_kernel.mf_kernel`) in numpy, bit for bit: its specification.

Every output pixel of the kernel depends on that pixel's frames alone, and every operation is an
exact integer sum or a correctly rounded float64 operation (+, -, *, /, sqrt, ceil; numba compiles
without fast-math, so nothing is fused or reordered). The same operations in the same order over
whole arrays therefore give the same bits: the group sums (exact, any order), the float sums over
the groups' nonzero weights in order, the masks, the kernel's own arctangent (``_atan2``: the same
polynomial, reduction and sign rules, its branch-free selects as ``np.where``), the MF chain (base
phase, eq. 7 steps, rounding with ties down, the pattern's range).

Used to check the C replica (:mod:`unwrap._fused_c`) on a small input in each process before it
runs, and by the tests (tests/test_fused_c.py: equal to the numba kernel bit for bit). About 10x
slower than the compiled kernels: not a decode path.
"""
from __future__ import annotations

import numpy as np

from . import _fused_consts as K


def atan2(y, x):
    """The kernel's ``_atan2`` over arrays (float64)."""
    ax, ay = np.abs(x), np.abs(y)
    mx, mn = np.maximum(ax, ay), np.minimum(ax, ay)
    big = mn > K.TAN_PI_8 * mx
    num = np.where(big, mn - mx, mn)
    den = np.where(big, mn + mx, mx)
    u = num / np.where(den > 0.0, den, 1.0)
    z = u * u
    p = K.R[10] * z
    for c in K.R[9:0:-1]:
        p = (p + c) * z
    p = p + K.R[0]
    r = u + u * (z * p)
    r = np.where(big, K.PI_4 + (r + K.PI_4_LO), r)
    r = np.where(ay > ax, K.PI_2 - r, r)
    r = np.where(np.signbit(x), K.PI - r, r)
    return np.copysign(r, y)


def _float_sum(y, w):
    """``sum_g w[g] * y[g]`` in float64 over the nonzero weights, g in order (0.0 when none)."""
    out = None
    for g in np.flatnonzero(w):
        t = w[g] * y[g].astype(np.float64)
        out = t if out is None else out + t
    return np.zeros(y.shape[1], np.float64) if out is None else out


def _in_pattern(Phi, k, g, kmax, p_lo, p_hi, wrap):
    if wrap > 0.0:
        low = g & (Phi < p_lo)
        high = g & ~low & (Phi >= p_hi)
        Phi = np.where(low, Phi + K.TWO_PI * wrap, np.where(high, Phi - K.TWO_PI * wrap, Phi))
        k = np.where(low, k + wrap, np.where(high, k - wrap, k))
    g = g & (Phi >= p_lo) & (Phi < p_hi) & (k >= 0.0) & (k <= kmax)
    return Phi, k, g


def mf_kernel(stacks, W, goff, grp_start, ent_n, ent_s, sum_all, ratios, cut, sat, lo, hi, min_mod, kmax,
              p_lo, p_hi, wrap, phase, order, valid, prior, A_out, B_out, lev_prior, lev_k):
    """:func:`unwrap._fused_kernel.mf_kernel`'s arguments (no ``sum_type``: sums are exact either
    way) and outputs, filled in place."""
    F = len(stacks)
    check_range = lo > -np.inf or hi < np.inf
    check_sat = sat < np.inf
    phis, ok = [], np.ones(phase.size, bool)
    for f in range(F):
        st = stacks[f]
        g0, g1 = int(goff[f]), int(goff[f + 1])
        y = np.empty((g1 - g0, st.shape[1]), np.int32)
        for g in range(g0, g1):
            acc = np.zeros(st.shape[1], np.int32)
            for e in range(int(grp_start[g]), int(grp_start[g + 1])):
                acc += int(ent_s[e]) * st[int(ent_n[e])].astype(np.int32)
            y[g - g0] = acc
        a = _float_sum(y, W[0, g0:g1])
        c = _float_sum(y, W[1, g0:g1])
        s = _float_sum(y, W[2, g0:g1])
        Bm = np.sqrt(c * c + s * s)
        defined = (Bm > 1e-9 * np.abs(a)) & (Bm > 0.0)
        oor = np.zeros_like(defined)
        if check_range:
            oor = (st.min(axis=0).astype(np.float64) < lo) | (st.max(axis=0).astype(np.float64) > hi)
        saturated = st.max(axis=0).astype(np.float64) >= sat if check_sat else np.zeros_like(defined)
        good = defined & ~(Bm < min_mod) & ~oor & ~saturated
        phis.append(np.where(good, atan2(s, c), np.nan))
        ok &= good
        if f == F - 1:
            A_out[:] = a
            B_out[:] = np.where(defined & ~oor, Bm, 0.0)
    d = phis[0] - cut
    Phi = np.where(d < 0.0, d + K.TWO_PI, d) + cut
    for i in range(1, F):
        pr = (ratios[i] * Phi - phis[i]) / K.TWO_PI
        k = np.ceil(pr - K.HALF_TIE)
        Phi = phis[i] + K.TWO_PI * k
        if lev_prior.shape[0]:
            lev_prior[i - 1], lev_k[i - 1] = pr, k
    g = ok & (k >= 0.0) & (k <= kmax)
    Phi, k, g = _in_pattern(Phi, k, g, kmax, p_lo, p_hi, wrap)
    phase[:] = np.where(g, Phi, np.nan)
    order[:] = np.where(g, k, -1.0).astype(np.int32)
    valid[:] = g
    prior[:] = np.where(ok, pr, np.nan)
