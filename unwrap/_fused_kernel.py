"""numba kernel of :func:`unwrap.fused_mf.mf_unwrap_stacks` (imported only when numba is installed).

One pass over the frames: for each block of pixels and each frequency, exact integer sums of
the frames that share a least-squares weight (``unwrap.fused_mf.factor_weights``: int16 for
8-bit frames, else int32; the background group's pass also finds the per-pixel maximum for the
saturation mask), the float64 sums ``[A, C, S] = W @ y`` over the groups in order, then per pixel
``B = sqrt(C^2 + S^2)``, the masks and the wrapped phase ``atan2(S, C)`` (block-sized scratch),
then the MF chain of :func:`unwrap.temporal.mf_unwrap` (base phase, eq. 7 steps, final masks)
with the reference's float64 operations in the same order. Blocks run in parallel (``prange``);
compiled code is cached on disk (``cache=True``), so only the first use on a machine pays the
compile time (~13 s).

``error_model="numpy"`` (IEEE division, no ZeroDivisionError checks), branch-free arithmetic and
one small function per loop (arrays arrive as arguments, so LLVM sees their data pointers as
loop invariant) let LLVM vectorise every per-pixel loop, the arctangent included.

Arctangent: ``_atan2`` reduces ``atan2(y, x)`` with ``mn = min(|x|,|y|)``, ``mx = max(|x|,|y|)``
to ``atan(u)``, ``u = mn/mx`` or, above ``tan(pi/8)``, ``u = (mn - mx)/(mn + mx)`` with
``atan(mn/mx) = pi/4 + atan(u)``, so |u| <= tan(pi/8) with one division; ``atan(u) = u + u z R(z)``,
``z = u^2``, R a degree-10 polynomial (coefficients below, our own fit); then the octant and
quadrant from the signs (IEEE signed zeros as C's atan2; finite arguments). Measured against
``numpy.arctan2``: at most 4.5e-16 rad (2 ulp) over 1e6 random points, octant boundaries and all
signed-zero cases (tests/test_unwrap_fused.py).
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from ._fused_consts import BLOCK as _BLOCK
from ._fused_consts import HALF_TIE as _HALF_TIE
from ._fused_consts import PI as _PI
from ._fused_consts import PI_2 as _PI_2
from ._fused_consts import PI_4 as _PI_4
from ._fused_consts import PI_4_LO as _PI_4_LO
from ._fused_consts import R as _R
from ._fused_consts import TAN_PI_8 as _TAN_PI_8
from ._fused_consts import TWO_PI as _TWO_PI

_R0, _R1, _R2, _R3, _R4, _R5, _R6, _R7, _R8, _R9, _R10 = _R
_JIT = dict(cache=True, error_model="numpy", nogil=True)


@nb.njit(inline="always", **_JIT)
def _atan2(y, x):
    """atan2(y, x) in [-pi, pi] (float64), branch-free so that loops calling it vectorise."""
    ax = abs(x)
    ay = abs(y)
    mx = max(ax, ay)
    mn = min(ax, ay)
    big = mn > _TAN_PI_8 * mx  # t = mn/mx > tan(pi/8): atan(t) = pi/4 + atan((t - 1)/(t + 1))
    num = mn - mx if big else mn
    den = mn + mx if big else mx
    u = num / (den if den > 0.0 else 1.0)  # |u| <= tan(pi/8)
    z = u * u
    p = (((((((((_R10 * z + _R9) * z + _R8) * z + _R7) * z + _R6) * z + _R5) * z + _R4) * z + _R3)
           * z + _R2) * z + _R1) * z + _R0
    r = u + u * (z * p)
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




@nb.njit(**_JIT)
def _extremes(st, s0, m, imax, imin, want_min):
    """Per-pixel max (and min when ``want_min``) over the N frames of one stack, pixels s0 .. s0+m-1."""
    if not want_min:
        r = st[0, s0:s0 + m]
        for j in range(m):
            imax[j] = r[j]
        n = 1
        while n + 4 <= st.shape[0]:
            r0 = st[n, s0:s0 + m]
            r1 = st[n + 1, s0:s0 + m]
            r2 = st[n + 2, s0:s0 + m]
            r3 = st[n + 3, s0:s0 + m]
            for j in range(m):
                imax[j] = max(max(imax[j], max(r0[j], r1[j])), max(r2[j], r3[j]))
            n += 4
        while n < st.shape[0]:
            r0 = st[n, s0:s0 + m]
            for j in range(m):
                imax[j] = max(imax[j], r0[j])
            n += 1
        return
    r = st[0, s0:s0 + m]
    for j in range(m):
        imax[j] = r[j]
        imin[j] = r[j]
    for n in range(1, st.shape[0]):
        r = st[n, s0:s0 + m]
        for j in range(m):
            imax[j] = max(imax[j], r[j])
            imin[j] = min(imin[j], r[j])


@nb.njit(**_JIT)
def _group_sum(st, s0, m, ent_n, ent_s, e, e_end, yg):
    """Exact integer ``yg[j] = sum_e ent_s[e] * st[ent_n[e], s0 + j]`` over entries e .. e_end-1."""
    first = True
    while e < e_end:
        if e + 4 <= e_end:
            r0 = st[ent_n[e], s0:s0 + m]
            r1 = st[ent_n[e + 1], s0:s0 + m]
            r2 = st[ent_n[e + 2], s0:s0 + m]
            r3 = st[ent_n[e + 3], s0:s0 + m]
            q0, q1, q2, q3 = ent_s[e], ent_s[e + 1], ent_s[e + 2], ent_s[e + 3]
            if first:
                for j in range(m):
                    yg[j] = (q0 * np.int32(r0[j]) + q1 * np.int32(r1[j])
                             + q2 * np.int32(r2[j]) + q3 * np.int32(r3[j]))
            else:
                for j in range(m):
                    yg[j] += (q0 * np.int32(r0[j]) + q1 * np.int32(r1[j])
                              + q2 * np.int32(r2[j]) + q3 * np.int32(r3[j]))
            e += 4
        elif e + 2 <= e_end:
            r0 = st[ent_n[e], s0:s0 + m]
            r1 = st[ent_n[e + 1], s0:s0 + m]
            q0, q1 = ent_s[e], ent_s[e + 1]
            if first:
                for j in range(m):
                    yg[j] = q0 * np.int32(r0[j]) + q1 * np.int32(r1[j])
            else:
                for j in range(m):
                    yg[j] += q0 * np.int32(r0[j]) + q1 * np.int32(r1[j])
            e += 2
        else:
            r0 = st[ent_n[e], s0:s0 + m]
            q0 = ent_s[e]
            if first:
                for j in range(m):
                    yg[j] = q0 * np.int32(r0[j])
            else:
                for j in range(m):
                    yg[j] += q0 * np.int32(r0[j])
            e += 1
        first = False


@nb.njit(**_JIT)
def _sum_and_max(st, s0, m, yg, imax):
    """``yg[j] = sum_n st[n, s0 + j]`` (exact integer) and ``imax[j] = max_n st[n, s0 + j]`` in
    one pass over the frames (the background group of equal shifts + the saturation test)."""
    N = st.shape[0]
    r0 = st[0, s0:s0 + m]
    for j in range(m):
        yg[j] = r0[j]
        imax[j] = r0[j]
    n = 1
    while n + 4 <= N:
        r0 = st[n, s0:s0 + m]
        r1 = st[n + 1, s0:s0 + m]
        r2 = st[n + 2, s0:s0 + m]
        r3 = st[n + 3, s0:s0 + m]
        for j in range(m):
            v0 = r0[j]
            v1 = r1[j]
            v2 = r2[j]
            v3 = r3[j]
            yg[j] += (np.int32(v0) + np.int32(v1)) + (np.int32(v2) + np.int32(v3))
            imax[j] = max(imax[j], max(max(v0, v1), max(v2, v3)))
        n += 4
    while n < N:
        r0 = st[n, s0:s0 + m]
        for j in range(m):
            yg[j] += np.int32(r0[j])
            imax[j] = max(imax[j], r0[j])
        n += 1


@nb.njit(**_JIT)
def _float_sum(y, w, out):
    """``out[j] = sum_g w[g] * y[g, j]`` in float64 over the nonzero weights, g in order."""
    m = out.size
    nz = np.flatnonzero(w)
    if nz.size == 0:
        for j in range(m):
            out[j] = 0.0
        return
    i = 0
    while i < nz.size:
        if i + 2 <= nz.size:
            wa = w[nz[i]]
            wb = w[nz[i + 1]]
            ya = y[nz[i]]
            yb = y[nz[i + 1]]
            if i == 0:
                for j in range(m):
                    out[j] = wa * np.float64(ya[j]) + wb * np.float64(yb[j])
            else:
                for j in range(m):
                    out[j] = (out[j] + wa * np.float64(ya[j])) + wb * np.float64(yb[j])
            i += 2
        else:
            wa = w[nz[i]]
            ya = y[nz[i]]
            if i == 0:
                for j in range(m):
                    out[j] = wa * np.float64(ya[j])
            else:
                for j in range(m):
                    out[j] += wa * np.float64(ya[j])
            i += 1


@nb.njit(**_JIT)
def _phase_and_masks(sa, sc, ss, imax, imin, lo, hi, sat, min_mod, ph_f, ok, bmod):
    """Wrapped phase (NaN where not valid), B and masks exactly as
    ``unwrap.phase_shift._wrapped_phase_numpy``; ``ok &= valid``."""
    for j in range(sa.size):
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


@nb.njit(**_JIT)
def _base(p0, cut, Phi_s):
    """unwrap.temporal.base_phase: remainder(phi - c, 2 pi) + c, for |phi - c| < 2 pi."""
    for j in range(p0.size):
        d = p0[j] - cut
        Phi_s[j] = (d + _TWO_PI if d < 0.0 else d) + cut


@nb.njit(**_JIT)
def _refine(p_i, ratio, Phi_s, pr_s, k_s):
    """unwrap.temporal.refine (eq. 7) in place: prior, k = round_order(prior) (ties down), Phi."""
    for j in range(p_i.size):
        phi = p_i[j]
        pr = (ratio * Phi_s[j] - phi) / _TWO_PI
        k = np.ceil(pr - _HALF_TIE)
        Phi_s[j] = phi + _TWO_PI * k
        pr_s[j] = pr
        k_s[j] = k


@nb.njit(**_JIT)
def _in_pattern(Phi, k, g, kmax, p_lo, p_hi, wrap):
    """unwrap.temporal.constrain_to_pattern for one pixel: (Phi, k, valid)."""
    if g and wrap > 0.0:
        if Phi < p_lo:
            Phi = Phi + _TWO_PI * wrap
            k = k + wrap
        elif Phi >= p_hi:
            Phi = Phi - _TWO_PI * wrap
            k = k - wrap
    g = g & (Phi >= p_lo) & (Phi < p_hi) & (k >= 0.0) & (k <= kmax)
    return Phi, k, g


@nb.njit(**_JIT)
def _final(ok, k_s, Phi_s, pr_s, kmax, p_lo, p_hi, wrap, phase, order, valid, prior):
    """unwrap.temporal.finish_unwrapped for one block (output slices)."""
    for j in range(ok.size):
        k = k_s[j]
        g = ok[j] & (k >= 0.0) & (k <= kmax)
        Phi, k, g = _in_pattern(Phi_s[j], k, g, kmax, p_lo, p_hi, wrap)
        phase[j] = Phi if g else np.nan
        order[j] = np.int32(k if g else -1.0)
        valid[j] = g
        prior[j] = pr_s[j] if ok[j] else np.nan


@nb.njit(**_JIT)
def _refine_final(p_i, ratio, Phi_s, ok, kmax, p_lo, p_hi, wrap, phase, order, valid, prior):
    """The last :func:`_refine` step fused with :func:`_final` (no intermediate arrays)."""
    for j in range(p_i.size):
        phi = p_i[j]
        pr = (ratio * Phi_s[j] - phi) / _TWO_PI
        k = np.ceil(pr - _HALF_TIE)
        g = ok[j] & (k >= 0.0) & (k <= kmax)
        Phi, k, g = _in_pattern(phi + _TWO_PI * k, k, g, kmax, p_lo, p_hi, wrap)
        phase[j] = Phi if g else np.nan
        order[j] = np.int32(k if g else -1.0)
        valid[j] = g
        prior[j] = pr if ok[j] else np.nan


@nb.njit(**_JIT)
def _copy(src, dst):
    for j in range(src.size):
        dst[j] = src[j]


@nb.njit(parallel=True, **_JIT)
def mf_kernel(stacks, sum_type, W, goff, grp_start, ent_n, ent_s, sum_all, ratios, cut, sat, lo, hi,
              min_mod, kmax, p_lo, p_hi, wrap, phase, order, valid, prior, A_out, B_out, lev_prior, lev_k):
    """Fused wrapped phase (every stack) + MF unwrapping.

    stacks: tuple of F (N_f, n_pix) uint8/uint16 C-contiguous arrays; sum_type: an empty array
    of the integer type of the group sums (int16 when every sum fits, else int32; the narrower
    type doubles the SIMD lanes). Least-squares weights
    factored as ``P_f = W[:, goff[f]:goff[f+1]] @ Q_f`` (``unwrap.fused_mf.factor_weights``):
    group g's integer sum takes frames ent_n[e] with signs ent_s[e] (int32 +-1) for
    e in grp_start[g] .. grp_start[g+1]-1; W (3, G) float64; sum_all[f]: stack f's group that
    sums all frames with sign +1 (its pass also finds the maximum), or -1. ratios[i] =
    f_i / f_{i-1} (ratios[0] unused); cut: base-phase cut (rad); sat: saturation level (inf: none);
    lo, hi: valid range (+-inf: none); min_mod: low-modulation threshold; kmax: largest order;
    p_lo, p_hi: the pattern's absolute-phase range and wrap: orders one base period moves the
    result (0: none) (unwrap.temporal.constrain_to_pattern).
    Outputs (n_pix,): phase, order, valid, prior, A_out, B_out (highest frequency);
    lev_prior, lev_k: (F-1, n_pix) or (0, 0) when not wanted.
    """
    F = len(stacks)
    n_pix = phase.size
    want_levels = lev_prior.shape[0] > 0
    check_range = lo > -np.inf or hi < np.inf
    check_sat = sat < np.inf
    n_blocks = (n_pix + _BLOCK - 1) // _BLOCK
    g_max = 0
    for f in range(F):
        g_max = max(g_max, goff[f + 1] - goff[f])
    for b in nb.prange(n_blocks):
        s0 = b * _BLOCK
        m = min(_BLOCK, n_pix - s0)
        acc = np.empty((3, m), np.float64)
        bmod = np.empty(m, np.float64)
        phis = np.empty((F, m), np.float64)
        ok = np.ones(m, np.bool_)
        y = np.empty((g_max, m), sum_type.dtype)
        for f in range(F):
            st = stacks[f]
            imax = np.empty(m, st.dtype)
            imin = imax
            if check_range:
                imin = np.empty(m, st.dtype)
            g0 = goff[f]
            G = goff[f + 1] - g0
            g_all = sum_all[f]  # the group summing every frame with sign +1, or -1
            fuse_max = check_sat and not check_range and g_all >= 0
            if (check_range or check_sat) and not fuse_max:
                _extremes(st, s0, m, imax, imin, check_range)
            for g in range(G):
                if fuse_max and g == g_all:
                    _sum_and_max(st, s0, m, y[g], imax)
                else:
                    _group_sum(st, s0, m, ent_n, ent_s, grp_start[g0 + g], grp_start[g0 + g + 1],
                               y[g])
            a_row = A_out[s0:s0 + m] if f == F - 1 else acc[0]
            b_row = B_out[s0:s0 + m] if f == F - 1 else bmod
            _float_sum(y, W[0, g0:g0 + G], a_row)
            _float_sum(y, W[1, g0:g0 + G], acc[1])
            _float_sum(y, W[2, g0:g0 + G], acc[2])
            _phase_and_masks(a_row, acc[1], acc[2], imax, imin, lo, hi, sat, min_mod, phis[f], ok,
                             b_row)
        e = s0 + m
        # MF chain of unwrap.temporal.mf_unwrap, one frequency step at a time over the block
        Phi_s = np.empty(m, np.float64)
        _base(phis[0], cut, Phi_s)
        if want_levels:
            pr_s = np.empty(m, np.float64)
            k_s = np.empty(m, np.float64)
            for i in range(1, F):
                _refine(phis[i], ratios[i], Phi_s, pr_s, k_s)
                _copy(pr_s, lev_prior[i - 1, s0:e])
                _copy(k_s, lev_k[i - 1, s0:e])
            _final(ok, k_s, Phi_s, pr_s, kmax, p_lo, p_hi, wrap, phase[s0:e], order[s0:e], valid[s0:e],
                   prior[s0:e])
        else:
            pr_s = np.empty(m, np.float64)
            k_s = np.empty(m, np.float64)
            for i in range(1, F - 1):
                _refine(phis[i], ratios[i], Phi_s, pr_s, k_s)
            _refine_final(phis[F - 1], ratios[F - 1], Phi_s, ok, kmax, p_lo, p_hi, wrap, phase[s0:e],
                          order[s0:e], valid[s0:e], prior[s0:e])
