"""The fused MF kernel (:func:`unwrap._fused_kernel.mf_kernel`) in C, bit for bit, loaded with ctypes.

Why: the traditional ``calib unwrap`` spent ~1 s of CPU on numba's start-up (import, which imports
``scipy.linalg``; the lowering registries; the cached machine code), before its ~0.05 s kernel ran;
this library loads in ~1 ms. The source below is ``mf_kernel``'s functions line for line: the same
exact integer group sums, the float64 sums over the nonzero weights in order, the masks, the own
arctangent (the constants of :mod:`unwrap._fused_consts`, written as exact hexadecimal literals), the
MF chain with ties rounded down. Compiled without fast-math and with ``-ffp-contract=off``
(:mod:`unwrap._native`), as numba compiles, every output is the numba kernel's to the bit
(tests/test_fused_c.py); each process checks the library against the numpy replica
(:mod:`unwrap._fused_numpy`) on a small input before it uses it, and falls back where they differ.

Each call covers a range of pixels (every output pixel depends on its own frames alone), so
:func:`kernel`'s caller splits a frame into a few ranges run on threads (ctypes releases the GIL).
"""
from __future__ import annotations

import re

import numpy as np

from . import _fused_consts as K

_TEMPLATE = r"""
static void extremes_T(const T *const *rows, i64 N, i64 m, T *imax, T *imin, int want_min) {
    for (i64 j = 0; j < m; j++) imax[j] = rows[0][j];
    for (i64 n = 1; n < N; n++) {
        const T *r = rows[n];
        for (i64 j = 0; j < m; j++) imax[j] = r[j] > imax[j] ? r[j] : imax[j];
    }
    if (!want_min) return;
    for (i64 j = 0; j < m; j++) imin[j] = rows[0][j];
    for (i64 n = 1; n < N; n++) {
        const T *r = rows[n];
        for (i64 j = 0; j < m; j++) imin[j] = r[j] < imin[j] ? r[j] : imin[j];
    }
}

static void group_sum_T(const T *const *rows, const i64 *ent_n, const int *ent_s, i64 e, i64 e_end, i64 m,
                        int *restrict yg) {
    for (i64 j = 0; j < m; j++) yg[j] = 0;
    for (; e + 4 <= e_end; e += 4) {              /* four frames a pass: yg loaded and stored once */
        const T *restrict r0 = rows[ent_n[e]], *restrict r1 = rows[ent_n[e + 1]];
        const T *restrict r2 = rows[ent_n[e + 2]], *restrict r3 = rows[ent_n[e + 3]];
        int q0 = ent_s[e], q1 = ent_s[e + 1], q2 = ent_s[e + 2], q3 = ent_s[e + 3];
        for (i64 j = 0; j < m; j++)
            yg[j] += q0 * (int)r0[j] + q1 * (int)r1[j] + q2 * (int)r2[j] + q3 * (int)r3[j];
    }
    for (; e < e_end; e++) {
        const T *restrict r = rows[ent_n[e]];
        int q = ent_s[e];
        for (i64 j = 0; j < m; j++) yg[j] += q * (int)r[j];
    }
}

static void sum_and_max_T(const T *const *rows, i64 N, i64 m, int *yg, T *imax) {
    for (i64 j = 0; j < m; j++) yg[j] = rows[0][j];
    for (i64 j = 0; j < m; j++) imax[j] = rows[0][j];
    for (i64 n = 1; n < N; n++) {
        const T *r = rows[n];
        for (i64 j = 0; j < m; j++) yg[j] += (int)r[j];
        for (i64 j = 0; j < m; j++) imax[j] = r[j] > imax[j] ? r[j] : imax[j];
    }
}

int mf_range_T(int F, const void *const *stacks, const i64 *nframes, const double *W, i64 Gt,
               const i64 *goff, const i64 *grp_start, const i64 *ent_n, const int *ent_s,
                      const i64 *sum_all, const double *ratios, double cut, double sat, double lo, double hi,
                      double min_mod, double kmax, double p_lo, double p_hi, double wrap, i64 n_pix, i64 p0,
                      i64 p1, double *phase, int *order, unsigned char *valid, double *prior, double *A_out,
                      double *B_out, i64 n_lev, double *lev_prior, double *lev_k) {
    int check_range = lo > -INFINITY || hi < INFINITY, check_sat = sat < INFINITY;
    i64 g_max = 0, n_max = 0;
    for (int f = 0; f < F; f++) {
        if (goff[f + 1] - goff[f] > g_max) g_max = goff[f + 1] - goff[f];
        if (nframes[f] > n_max) n_max = nframes[f];
    }
    double *acc = malloc(sizeof(double) * BLOCK * (4 + F + 3));
    int *y = malloc(sizeof(int) * BLOCK * (g_max > 0 ? g_max : 1));
    T *ext = calloc(2 * BLOCK, sizeof(T));    /* defined when not computed: compared with +-inf then */
    unsigned char *ok = malloc(BLOCK);
    const T **rows = malloc(sizeof(T *) * (n_max > 0 ? n_max : 1));
    if (!acc || !y || !ext || !ok || !rows) { free(acc); free(y); free(ext); free(ok); free(rows); return -1; }
    double *a0 = acc, *c0 = acc + BLOCK, *s0v = acc + 2 * BLOCK, *bmod = acc + 3 * BLOCK, *phis = acc + 4 * BLOCK;
    double *Phi_s = phis + (i64)F * BLOCK, *pr_s = Phi_s + BLOCK, *k_s = pr_s + BLOCK;
    T *imax = ext, *imin = check_range ? ext + BLOCK : ext;
    for (i64 s0 = p0; s0 < p1; s0 += BLOCK) {
        i64 m = p1 - s0 < BLOCK ? p1 - s0 : BLOCK;
        for (i64 j = 0; j < m; j++) ok[j] = 1;
        for (int f = 0; f < F; f++) {
            const T *st = (const T *)stacks[f];
            i64 N = nframes[f];
            for (i64 n = 0; n < N; n++) rows[n] = st + (size_t)n * n_pix + s0;
            i64 g0 = goff[f], G = goff[f + 1] - g0, g_all = sum_all[f];
            int fuse_max = check_sat && !check_range && g_all >= 0;
            if ((check_range || check_sat) && !fuse_max) extremes_T(rows, N, m, imax, imin, check_range);
            for (i64 g = 0; g < G; g++) {
                if (fuse_max && g == g_all) sum_and_max_T(rows, N, m, y + g * BLOCK, imax);
                else group_sum_T(rows, ent_n, ent_s, grp_start[g0 + g], grp_start[g0 + g + 1], m, y + g * BLOCK);
            }
            double *a_row = f == F - 1 ? A_out + s0 : a0, *b_row = f == F - 1 ? B_out + s0 : bmod;
            float_sum(y, W + g0, G, m, a_row);
            float_sum(y, W + Gt + g0, G, m, c0);
            float_sum(y, W + 2 * Gt + g0, G, m, s0v);
            double *ph_f = phis + (i64)f * BLOCK;
            for (i64 j = 0; j < m; j++) {
                double a = a_row[j], cc = c0[j], sn = s0v[j];
                double Bm = sqrt(cc * cc + sn * sn);
                int defined = (Bm > 1e-9 * fabs(a)) & (Bm > 0.0);
                int oor = ((double)imin[j] < lo) | ((double)imax[j] > hi);     /* false at lo, hi = -inf, inf */
                int saturated = (double)imax[j] >= sat;                        /* false at sat = inf */
                int good = defined & !(Bm < min_mod) & !oor & !saturated;
                double ph = atan2_k(sn, cc);
                ph_f[j] = good ? ph : NAN;
                ok[j] = ok[j] & good;
                b_row[j] = (defined & !oor) ? Bm : 0.0;
            }
        }
        mf_chain(F, phis, ratios, cut, kmax, p_lo, p_hi, wrap, ok, m, n_pix, s0, Phi_s, pr_s, k_s, phase, order,
                 valid, prior, n_lev, lev_prior, lev_k);
    }
    free(acc); free(y); free(ext); free(ok); free(rows);
    return 0;
}
"""

_COMMON = r"""
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <stddef.h>

typedef int64_t i64;    /* every integer argument: 64 bits on every platform (ctypes.c_int64) */

#define BLOCK ((i64){BLOCK})
static const double R0 = {R0}, R1 = {R1}, R2 = {R2}, R3 = {R3}, R4 = {R4}, R5 = {R5}, R6 = {R6}, R7 = {R7},
                    R8 = {R8}, R9 = {R9}, R10 = {R10};
static const double TAN_PI_8 = {TAN_PI_8}, PI_ = {PI}, PI_2 = {PI_2}, PI_4 = {PI_4}, PI_4_LO = {PI_4_LO},
                    TWO_PI = {TWO_PI}, HALF_TIE = {HALF_TIE};

static inline double atan2_k(double y, double x) {
    double ax = fabs(x), ay = fabs(y);
    double mx = ax > ay ? ax : ay, mn = ax < ay ? ax : ay;
    int big = mn > TAN_PI_8 * mx;
    double num = big ? mn - mx : mn, den = big ? mn + mx : mx;
    double u = num / (den > 0.0 ? den : 1.0);
    double z = u * u;
    double p = (((((((((R10 * z + R9) * z + R8) * z + R7) * z + R6) * z + R5) * z + R4) * z + R3) * z + R2) * z
                + R1) * z + R0;
    double r = u + u * (z * p);
    double rb = PI_4 + (r + PI_4_LO);
    r = big ? rb : r;
    double rs = PI_2 - r;
    r = ay > ax ? rs : r;
    double rn = PI_ - r;
    r = signbit(x) ? rn : r;
    return copysign(r, y);
}

/* out[j] = sum_g w[g] * y[g][j] over the nonzero weights, g in order */
static void float_sum(const int *y, const double *w, i64 G, i64 m, double *out) {
    int first = 1;
    for (i64 g = 0; g < G; g++) {
        if (w[g] == 0.0) continue;
        double wg = w[g];
        const int *yg = y + g * BLOCK;
        if (first) for (i64 j = 0; j < m; j++) out[j] = wg * (double)yg[j];
        else for (i64 j = 0; j < m; j++) out[j] = out[j] + wg * (double)yg[j];
        first = 0;
    }
    if (first) for (i64 j = 0; j < m; j++) out[j] = 0.0;
}

static void mf_chain(int F, const double *phis, const double *ratios, double cut, double kmax, double p_lo,
                     double p_hi, double wrap, const unsigned char *ok, i64 m, i64 n_pix, i64 s0, double *Phi_s,
                     double *pr_s, double *k_s, double *phase, int *order, unsigned char *valid, double *prior,
                     i64 n_lev, double *lev_prior, double *lev_k) {
    for (i64 j = 0; j < m; j++) {
        double d = phis[j] - cut;
        Phi_s[j] = (d < 0.0 ? d + TWO_PI : d) + cut;
    }
    for (int i = 1; i < F; i++) {
        const double *p_i = phis + (i64)i * BLOCK;
        double ratio = ratios[i];
        for (i64 j = 0; j < m; j++) {
            double phi = p_i[j];
            double pr = (ratio * Phi_s[j] - phi) / TWO_PI;
            double k = ceil(pr - HALF_TIE);
            Phi_s[j] = phi + TWO_PI * k;
            pr_s[j] = pr;
            k_s[j] = k;
        }
        if (n_lev > 0)
            for (i64 j = 0; j < m; j++) {
                lev_prior[(size_t)(i - 1) * n_pix + s0 + j] = pr_s[j];
                lev_k[(size_t)(i - 1) * n_pix + s0 + j] = k_s[j];
            }
    }
    for (i64 j = 0; j < m; j++) {
        double k = k_s[j], Phi = Phi_s[j];
        int g = ok[j] & (k >= 0.0) & (k <= kmax);
        int w = g & (wrap > 0.0), low = w & (Phi < p_lo), high = w & !low & (Phi >= p_hi);
        double Pu = Phi + TWO_PI * wrap, ku = k + wrap, Pd = Phi - TWO_PI * wrap, kd = k - wrap;
        Phi = low ? Pu : Phi;                     /* low and high exclusive */
        Phi = high ? Pd : Phi;
        k = low ? ku : k;
        k = high ? kd : k;
        g = g & (Phi >= p_lo) & (Phi < p_hi) & (k >= 0.0) & (k <= kmax);
        phase[s0 + j] = g ? Phi : NAN;
        double kk = g ? k : -1.0;
        order[s0 + j] = (int)kk;
        valid[s0 + j] = (unsigned char)g;
        prior[s0 + j] = ok[j] ? pr_s[j] : NAN;
    }
}
"""


def source() -> str:
    """The C source: the shared part, then the per-pixel-type functions for uint8 and uint16."""
    consts = {f"R{i}": float.hex(v) for i, v in enumerate(K.R)}
    consts.update({name: float.hex(getattr(K, name)) for name in
                   ("TAN_PI_8", "PI", "PI_2", "PI_4", "PI_4_LO", "TWO_PI", "HALF_TIE")})
    common = _COMMON.replace("{BLOCK}", str(K.BLOCK))
    for name, value in consts.items():
        common = common.replace("{" + name + "}", value)
    typed = [re.sub(r"\bT\b", ctype, _TEMPLATE.replace("_T(", f"_{tag}("))
             for tag, ctype in (("u8", "unsigned char"), ("u16", "unsigned short"))]
    return common + "".join(typed)


_LIB = []


def _load(weights):
    """``{dtype: ctypes function}`` of the checked library, or None (module docstring); ``weights``:
    :func:`unwrap.fused_mf._kernel_weights` (passed in: this module imports nothing of fused_mf)."""
    from ._native import build

    return build("fused_mf", source(), lambda dll: _bind(dll, weights))


def _bind(dll, weights):
    """The typed ``mf_range_*`` functions of ``dll`` if they give the numpy replica's bits, else None
    (:func:`unwrap._native.build`'s check)."""
    import ctypes

    ptr, lng, dbl = ctypes.c_void_p, ctypes.c_int64, ctypes.c_double      # int64_t on the C side
    funcs = {}
    for dtype, tag in ((np.dtype(np.uint8), "u8"), (np.dtype(np.uint16), "u16")):
        f = getattr(dll, f"mf_range_{tag}")            # AttributeError: not this library (build: None)
        f.argtypes = [ctypes.c_int, ptr, ptr, ptr, lng, ptr, ptr, ptr, ptr, ptr, ptr, dbl, dbl, dbl, dbl, dbl, dbl,
                      dbl, dbl, dbl, lng, lng, lng, ptr, ptr, ptr, ptr, ptr, ptr, lng, ptr, ptr]
        f.restype = ctypes.c_int
        funcs[dtype] = f
    return funcs if _same_bits(funcs, weights) else None


def _call(f, stacks, W, goff, grp_start, ent_n, ent_s, sum_all, ratios, cut, sat, lo, hi, min_mod, kmax, p_lo, p_hi,
          wrap, phase, order, valid, prior, A_out, B_out, lev_prior, lev_k, p0, p1):
    """One call of the library over pixels ``p0 .. p1 - 1`` (arrays as :func:`run`'s)."""
    import ctypes

    F, n_pix = len(stacks), phase.size
    ptrs = (ctypes.c_void_p * F)(*[s.ctypes.data for s in stacks])
    nframes = np.array([s.shape[0] for s in stacks], np.int64)
    c = np.ascontiguousarray
    W, goff, grp_start, ent_n = c(W, np.float64), c(goff, np.int64), c(grp_start, np.int64), c(ent_n, np.int64)
    ent_s, sum_all, ratios = c(ent_s, np.int32), c(sum_all, np.int64), c(ratios, np.float64)
    rc = f(F, ctypes.cast(ptrs, ctypes.c_void_p), nframes.ctypes.data, W.ctypes.data, W.shape[1], goff.ctypes.data,
           grp_start.ctypes.data, ent_n.ctypes.data, ent_s.ctypes.data, sum_all.ctypes.data, ratios.ctypes.data,
           cut, sat, lo, hi, min_mod, kmax, p_lo, p_hi, wrap, n_pix, p0, p1, phase.ctypes.data, order.ctypes.data,
           valid.ctypes.data, prior.ctypes.data, A_out.ctypes.data, B_out.ctypes.data, lev_prior.shape[0],
           lev_prior.ctypes.data, lev_k.ctypes.data)
    if rc != 0:      # its few KB of block buffers: the process is out of memory, so is every other engine
        from .errors import UnwrapError

        raise UnwrapError(f"out of memory: the fused MF decode could not allocate its block buffers "
                          f"({n_pix} pixels, {F} frequencies); free memory and run it again")


def _check_case(weights, seed: int, dtype, steps, levels: bool, sat: float, lo: float, hi: float,
                n_pix: int = 300, wrap: float = 0.0):
    """A small noisy MF input with dark, flat, saturated and out-of-range pixels, in the kernel's
    flat layout: (stacks, the scalar and weight arguments, fresh outputs); ``weights``:
    :func:`unwrap.fused_mf._kernel_weights`. ``n_pix`` above :data:`K.BLOCK <unwrap._fused_consts.BLOCK>`
    covers a full block and the next; ``wrap`` > 0 narrows the pattern's range to orders
    ``wrap / 2 .. 36 - wrap / 2`` so that results move up and down by ``wrap`` orders."""
    from .phase_shift import equal_shifts

    rng = np.random.default_rng(seed)
    top = np.iinfo(dtype).max
    x = np.linspace(0.0, 1.0, n_pix)
    stacks = []
    for f, N in zip((1.0, 6.0, 36.0), steps):
        d = equal_shifts(N)[:, None]
        I = top * (0.45 + 0.4 * np.cos(2 * np.pi * f * x[None, :] - d)) + rng.normal(0, 0.01 * top, (N, n_pix))
        I[:, :20] = 0.0                                   # dark
        I[:, 20:40] = 0.3 * top                           # flat
        I[:, 40:45] = top                                 # saturated
        stacks.append(np.clip(np.rint(I), 0, top).astype(dtype))
    stacks[-1][0, 60:64] = top                             # one saturated frame
    W, goff, grp_start, ent_n, ent_s, sum_all = weights(tuple(tuple(equal_shifts(N).tolist()) for N in steps))
    ratios = np.array([0.0, 6.0, 6.0])
    n_lev = 2 if levels else 0
    outs = (np.empty(n_pix), np.empty(n_pix, np.int32), np.empty(n_pix, bool), np.empty(n_pix), np.empty(n_pix),
            np.empty(n_pix), np.empty((n_lev, n_pix if levels else 0)), np.empty((n_lev, n_pix if levels else 0)))
    p_lo, p_hi = 2 * np.pi * (wrap / 2), 2 * np.pi * (36.0 - wrap / 2)
    args = (W, goff, grp_start, ent_n, ent_s, sum_all, ratios, 0.4, sat, lo, hi, 0.02 * top, 36.0, p_lo, p_hi,
            float(wrap))
    return stacks, args, outs


#: :func:`_check_case`'s arguments of the per-process check (:func:`_same_bits`)
CHECK_CASES = ((0, np.uint8, (12, 12, 12), True, 255.0, -np.inf, np.inf),
               (1, np.uint16, (4, 7, 5), False, np.inf, 30.0, 60000.0),
               (2, np.uint8, (3, 9, 12), False, np.inf, -np.inf, np.inf, 300, 12.0),
               (3, np.uint16, (3, 3, 3), True, 65535.0, -np.inf, np.inf, K.BLOCK + 100))


def _same_bits(funcs, weights) -> bool:
    """Whether the library gives the numpy replica's bits (:mod:`unwrap._fused_numpy`) on small inputs
    of both pixel types: equal and unequal step counts, with and without levels, saturation and a
    valid range, a frame of more than one block, the pattern's wrap both ways (a few ms once per
    process)."""
    from ._fused_numpy import mf_kernel as reference

    for case in CHECK_CASES:
        stacks, args, a = _check_case(weights, *case)
        b = tuple(np.empty_like(x) for x in a)
        _call(funcs[stacks[0].dtype], stacks, *args, *a, 0, a[0].size)
        reference(stacks, *args, *b)
        if any(x.tobytes() != y.tobytes() for x, y in zip(a, b)):
            return False
    return True


def kernel(weights):
    """``{dtype: function}`` of the checked library (uint8, uint16), or None where there is no C
    compiler, the cache cannot be used or the bits differ (then numba's kernel runs). ``weights``:
    :func:`unwrap.fused_mf._kernel_weights` (for the check)."""
    if not _LIB:
        _LIB.append(_load(weights))
    return _LIB[0]


#: pixels below which a frame is one call (threads cost more than they save)
SPLIT_MIN = 1 << 16


def run(funcs, stacks, W, goff, grp_start, ent_n, ent_s, sum_all, ratios, cut, sat, lo, hi, min_mod, kmax, p_lo,
        p_hi, wrap, phase, order, valid, prior, A_out, B_out, lev_prior, lev_k) -> None:
    """:func:`unwrap._fused_kernel.mf_kernel`'s arguments (no ``sum_type``) and outputs, filled in
    place by the library, the frame split into block-aligned ranges on the package's thread pool
    (:mod:`unwrap._threads`): every pixel is computed alone, so the split does not change a bit."""
    import os

    from ._threads import pool

    f = funcs[stacks[0].dtype]
    n_pix = phase.size
    if n_pix == 0:
        return
    args = (stacks, W, goff, grp_start, ent_n, ent_s, sum_all, ratios, cut, sat, lo, hi, min_mod, kmax, p_lo, p_hi,
            wrap, phase, order, valid, prior, A_out, B_out, lev_prior, lev_k)
    parts = min(os.cpu_count() or 1, 4) if n_pix >= SPLIT_MIN else 1
    step = -(-n_pix // (parts * K.BLOCK)) * K.BLOCK
    bounds = [(p0, min(p0 + step, n_pix)) for p0 in range(0, n_pix, step)] or [(0, 0)]
    if len(bounds) == 1:
        _call(f, *args, *bounds[0])
        return
    for _ in pool("fused-mf").map(lambda b: _call(f, *args, *b), bounds):
        pass
