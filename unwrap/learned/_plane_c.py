"""The plane-fit kernel of :mod:`unwrap.learned._plane_kernel` in C, bit for bit, loaded with ctypes.

Why: the numpy replica (:mod:`unwrap.learned._plane_numpy`) spares a one-capture ``calib unwrap
--model`` numba's ~1 s of start-up but spends ~0.1 s of CPU a box on numpy's per-step overhead;
the same loops in C take ~4-7 ms a box and load in ~1 ms. The source below is
``_plane_kernel``'s functions line for line (one thread: no ``prange``), except that pass 2's three
sweeps over the moments per output row (shift, the row leaving, the row entering) run as one sweep,
and the solve picks between its two quotients without a branch: per element the same operations in
the same order, written so that the compiler vectorises them over x (each plane a ``restrict``
argument; elementwise vector arithmetic rounds as the scalar one does). Compiled once by the system
C compiler with :data:`unwrap._native.FLAGS` (``-O3 -march=native``, no fast-math,
``-ffp-contract=off``: no fused multiply-adds, as numba compiles), and cached on disk by :func:`unwrap._native.build` (the same cache and rules as the
traditional decode's fused kernel, :mod:`unwrap._fused_c`). Same operations in the same order: the outputs are bitwise the compiled
kernel's (tests/test_plane_numpy.py); each process checks that on a small frame against the numpy
replica before using the library (a compiler that defaults to fast-math, a foreign or damaged file)
and falls back to numpy where the bits differ.

:func:`kernel` returns ``plane_filter_c(Phi, valid, r)``, or None where there is no C compiler or
the cache cannot be written (the caller then runs the numpy replica).
"""
from __future__ import annotations


import numpy as np

BLOCK = 64
"""Outputs per sliding run (:data:`unwrap.learned._plane_kernel.BLOCK`; a test holds them equal)."""


_SOURCE = r"""
#include <stddef.h>
#include <stdint.h>

typedef int64_t i64;    /* every integer argument: 64 bits on every platform (ctypes.c_int64) */

static void row_block(const double *Phi, const unsigned char *valid, i64 W, i64 r, i64 y, i64 hy, i64 x0,
                      i64 x1, double *h, size_t HW) {
    double a0 = 0.0, a1 = 0.0, a2 = 0.0, a3 = 0.0, a4 = 0.0;
    const double *P = Phi + (size_t)y * W;
    const unsigned char *v = valid + (size_t)y * W;
    i64 lo = x0 - r > 0 ? x0 - r : 0, hi = x0 + r < W - 1 ? x0 + r : W - 1;
    for (i64 xx = lo; xx <= hi; xx++) {
        if (v[xx]) {
            i64 d = xx - x0;
            double p = P[xx];
            a0 += 1.0;
            a1 += (double)d;
            a2 += (double)(d * d);
            a3 += p;
            a4 += p * (double)d;
        }
    }
    i64 x = x0;
    for (;;) {
        size_t i = (size_t)hy * W + x;
        h[i] = a0; h[HW + i] = a1; h[2 * HW + i] = a2; h[3 * HW + i] = a3; h[4 * HW + i] = a4;
        x += 1;
        if (x >= x1) break;
        a2 = a2 - 2.0 * a1 + a0;
        a1 = a1 - a0;
        a4 = a4 - a3;
        i64 xo = x - r - 1;
        if (xo >= 0 && v[xo]) {
            double p = P[xo];
            a0 -= 1.0;
            a1 += (double)(r + 1);
            a2 -= (double)((r + 1) * (r + 1));
            a3 -= p;
            a4 += p * (double)(r + 1);
        }
        i64 xi = x + r;
        if (xi < W && v[xi]) {
            double p = P[xi];
            a0 += 1.0;
            a1 += (double)r;
            a2 += (double)(r * r);
            a3 += p;
            a4 += p * (double)r;
        }
    }
}

/* The plane at every pixel of row y from its box's moments (S: 9 planes of W): as solve() was, written
   branch-free (both quotients computed, one kept: the same value, bit for bit) with every plane its own
   restrict argument, so that the compiler vectorises it over x. */
static void solve_planes(i64 W, const double *restrict P, const unsigned char *restrict v, const double *restrict S0,
                         const double *restrict S1, const double *restrict S2, const double *restrict S3,
                         const double *restrict S4, const double *restrict S5, const double *restrict S6,
                         const double *restrict S7, const double *restrict S8, double *restrict o) {
    for (i64 x = 0; x < W; x++) {
        double S0x = S0[x], Sx = S1[x], Sy = S2[x], Sxx = S3[x], Syy = S4[x];
        double Sxy = S5[x], SP = S6[x], SxP = S7[x], SyP = S8[x];
        double det = S0x * (Sxx * Syy - Sxy * Sxy) - Sx * (Sx * Syy - Sxy * Sy) + Sy * (Sx * Sxy - Sxx * Sy);
        double t = Sxx + Syy;
        double scale = S0x * (t * t) + 1e-12;
        double num = SP * (Sxx * Syy - Sxy * Sxy) - Sx * (SxP * Syy - Sxy * SyP) + Sy * (SxP * Sxy - Sxx * SyP);
        double plane = num / det;
        double mean = SP / (S0x < 1.0 ? 1.0 : S0x);
        double fit = (S0x >= 3.0 && det > 1e-6 * scale) ? plane : mean;
        o[x] = v[x] ? fit : P[x];
    }
}

static void solve(const double *Phi, const unsigned char *valid, i64 W, i64 y, const double *S, double *out) {
    size_t i = (size_t)y * W;
    solve_planes(W, Phi + i, valid + i, S, S + W, S + 2 * W, S + 3 * W, S + 4 * W, S + 5 * W, S + 6 * W, S + 7 * W,
                 S + 8 * W, out + i);
}

static void add_row(double *S, const double *h, i64 W, size_t HW, i64 yy, double d, double sign) {
    const double *h0r = h + (size_t)yy * W, *h1r = h + HW + (size_t)yy * W, *h2r = h + 2 * HW + (size_t)yy * W;
    const double *h3r = h + 3 * HW + (size_t)yy * W, *h4r = h + 4 * HW + (size_t)yy * W;
    for (i64 x = 0; x < W; x++) {
        double h0 = h0r[x], h1 = h1r[x], h3 = h3r[x];
        S[x] += sign * h0;
        S[W + x] += sign * h1;
        S[2 * W + x] += sign * (h0 * d);
        S[3 * W + x] += sign * h2r[x];
        S[4 * W + x] += sign * (h0 * (d * d));
        S[5 * W + x] += sign * (h1 * d);
        S[6 * W + x] += sign * h3;
        S[7 * W + x] += sign * h4r[x];
        S[8 * W + x] += sign * (h3 * d);
    }
}

/* One output row further in pass 2, for every x: the moments shifted to the new centre, the pass-1 row
   leaving the box (r0..r4, or none) and the row entering it (a0..a4, or none): per element add_row's
   operations in their order (shift, remove, add), in one pass over S instead of three. Every plane is its
   own restrict argument (they do not overlap) so that the compiler vectorises the loop over x:
   elementwise, the same operations, the same bits. */
#define STEP_ROW(NAME, REM, ADD)                                                                           \
static void NAME(i64 W, double *restrict S0, double *restrict S1, double *restrict S2, double *restrict S3,  \
                 double *restrict S4, double *restrict S5, double *restrict S6, double *restrict S7,          \
                 double *restrict S8, const double *restrict r0, const double *restrict r1,                  \
                 const double *restrict r2, const double *restrict r3, const double *restrict r4,            \
                 const double *restrict a0, const double *restrict a1, const double *restrict a2,            \
                 const double *restrict a3, const double *restrict a4, double dr, double da) {               \
    for (i64 x = 0; x < W; x++) {                                                                          \
        double s0 = S0[x], s1 = S1[x], s2 = S2[x], s3 = S3[x], s4 = S4[x];                                  \
        double s5 = S5[x], s6 = S6[x], s7 = S7[x], s8 = S8[x];                                              \
        s4 = s4 - 2.0 * s2 + s0;                                                                           \
        s2 = s2 - s0;                                                                                      \
        s5 = s5 - s1;                                                                                      \
        s8 = s8 - s6;                                                                                      \
        if (REM) {                                                                                         \
            double h0 = r0[x], h1 = r1[x], h3 = r3[x];                                                     \
            s0 += -1.0 * h0; s1 += -1.0 * h1; s2 += -1.0 * (h0 * dr); s3 += -1.0 * r2[x];                  \
            s4 += -1.0 * (h0 * (dr * dr)); s5 += -1.0 * (h1 * dr); s6 += -1.0 * h3;                        \
            s7 += -1.0 * r4[x]; s8 += -1.0 * (h3 * dr);                                                    \
        }                                                                                                  \
        if (ADD) {                                                                                         \
            double h0 = a0[x], h1 = a1[x], h3 = a3[x];                                                     \
            s0 += 1.0 * h0; s1 += 1.0 * h1; s2 += 1.0 * (h0 * da); s3 += 1.0 * a2[x];                      \
            s4 += 1.0 * (h0 * (da * da)); s5 += 1.0 * (h1 * da); s6 += 1.0 * h3;                           \
            s7 += 1.0 * a4[x]; s8 += 1.0 * (h3 * da);                                                      \
        }                                                                                                  \
        S0[x] = s0; S1[x] = s1; S2[x] = s2; S3[x] = s3; S4[x] = s4;                                        \
        S5[x] = s5; S6[x] = s6; S7[x] = s7; S8[x] = s8;                                                    \
    }                                                                                                      \
}
STEP_ROW(step_both, 1, 1)
STEP_ROW(step_rem, 1, 0)
STEP_ROW(step_add, 0, 1)
STEP_ROW(step_none, 0, 0)

static void step_row(double *S, i64 W, const double *hr, const double *ha, size_t HW, double dr, double da) {
    /* hr, ha: the leaving and entering pass-1 rows (plane stride HW), or NULL */
    static const double none = 0.0;
    const double *r = hr ? hr : &none, *a = ha ? ha : &none;
    size_t hr_s = hr ? HW : 0, ha_s = ha ? HW : 0;
    void (*f)(i64, double *, double *, double *, double *, double *, double *, double *, double *, double *,
              const double *, const double *, const double *, const double *, const double *,
              const double *, const double *, const double *, const double *, const double *, double, double)
        = hr ? (ha ? step_both : step_rem) : (ha ? step_add : step_none);
    f(W, S, S + W, S + 2 * W, S + 3 * W, S + 4 * W, S + 5 * W, S + 6 * W, S + 7 * W, S + 8 * W,
      r, r + hr_s, r + 2 * hr_s, r + 3 * hr_s, r + 4 * hr_s, a, a + ha_s, a + 2 * ha_s, a + 3 * ha_s, a + 4 * ha_s, dr, da);
}

static void col_block(const double *Phi, const unsigned char *valid, i64 H, i64 W, i64 r, i64 y0, i64 y1,
                      const double *h, size_t HW, i64 off, double *out, double *S) {
    /* h: the pass-1 rows from row off on (plane stride HW) */
    for (i64 k = 0; k < 9 * W; k++) S[k] = 0.0;
    i64 lo = y0 - r > 0 ? y0 - r : 0, hi = y0 + r < H - 1 ? y0 + r : H - 1;
    for (i64 yy = lo; yy <= hi; yy++) add_row(S, h, W, HW, yy - off, (double)(yy - y0), 1.0);
    i64 y = y0;
    for (;;) {
        solve(Phi, valid, W, y, S, out);
        y += 1;
        if (y >= y1) break;
        step_row(S, W, y - r - 1 >= 0 ? h + (size_t)(y - r - 1 - off) * W : 0,
                 y + r < H ? h + (size_t)(y + r - off) * W : 0, HW, (double)(-r - 1), (double)r);
    }
}

/* Row blocks b0 .. b1 - 1 (of ``block`` rows): each block's pass-1 rows (its own and r above and below,
   computed again for each block that needs them: the same values) into hb, 5 planes of (block + 2 r)
   rows, then pass 2: the buffer stays in cache, and blocks are independent (threads). */
void plane_filter(const double *Phi, const unsigned char *valid, i64 H, i64 W, i64 r, i64 block, i64 b0, i64 b1,
                  double *hb, double *S, double *out) {
    size_t HB = (size_t)(block + 2 * r) * W;
    for (i64 b = b0; b < b1; b++) {
        i64 y0 = b * block, y1 = y0 + block < H ? y0 + block : H;
        i64 lo = y0 - r > 0 ? y0 - r : 0, hi = y1 - 1 + r < H - 1 ? y1 - 1 + r : H - 1;
        for (i64 y = lo; y <= hi; y++)
            for (i64 x0 = 0; x0 < W; x0 += block)
                row_block(Phi, valid, W, r, y, y - lo, x0, x0 + block < W ? x0 + block : W, hb, HB);
        col_block(Phi, valid, H, W, r, y0, y1, hb, HB, lo, out, S);
    }
}
"""

_LIB = []


def _bind(dll):
    """``plane_filter`` of ``dll``, typed, if it gives the numpy replica's bits (:func:`_same_bits`);
    else None (:func:`unwrap._native.build`'s check)."""
    import ctypes

    f = dll.plane_filter
    ptr, lng = ctypes.c_void_p, ctypes.c_int64      # int64_t on the C side (not long: 32 bits on Windows)
    f.argtypes, f.restype = [ptr, ptr, lng, lng, lng, lng, lng, lng, ptr, ptr, ptr], None
    return f if _same_bits(f) else None


def _build():
    """The checked library's function, compiling it unless cached (:func:`unwrap._native.build`:
    a damaged cached file rebuilt, a refused build remembered); None when that cannot be done."""
    from .._native import build

    return build("plane_filter", _SOURCE, _bind)


def _same_bits(f) -> bool:
    """Whether the library gives the numpy replica's bits on a small noisy frame with holes, two
    blocks each way and both boxes' radii (a few ms once per process; module docstring)."""
    from ._plane_numpy import plane_filter_numpy

    rng = np.random.default_rng(7)
    Phi, valid = rng.normal(0.0, 3.0, (13, 11)), rng.random((13, 11)) > 0.2
    for r in (3, 7):
        h, S, out = np.empty((5, 8 + 2 * r, 11)), np.empty((9, 11)), np.empty_like(Phi)       # held while f runs
        f(Phi.ctypes.data, valid.ctypes.data, 13, 11, r, 8, 0, 2, h.ctypes.data, S.ctypes.data, out.ctypes.data)
        if out.tobytes() != plane_filter_numpy(Phi, valid, r, block=8).tobytes():
            return False
    return True


def kernel():
    """``plane_filter_c(Phi, valid, r, block=BLOCK)`` (module docstring), or None."""
    if not _LIB:
        _LIB.append(_build())
    f = _LIB[0]
    if f is None:
        return None

    def plane_filter_c(Phi, valid, r, block: int = BLOCK):
        Phi = np.ascontiguousarray(Phi, dtype=np.float64)
        valid = np.ascontiguousarray(valid, dtype=bool)
        H, W = Phi.shape
        r, block = int(r), int(block)
        h, S, out = np.empty((5, block + 2 * r, W)), np.empty((9, W)), np.empty((H, W))
        f(Phi.ctypes.data, valid.ctypes.data, H, W, r, block, 0, -(-H // block), h.ctypes.data, S.ctypes.data,
          out.ctypes.data)
        return out
    plane_filter_c.one_thread = True        # a caller may run several on threads (fast_features.plane_filter)
    return plane_filter_c
