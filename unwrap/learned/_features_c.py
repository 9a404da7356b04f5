"""The learned path's numpy stages around the forward, for an MF pair and a physics-aware model, in C,
bit for bit, loaded with ctypes: the traditional decode of the pair (:func:`unwrap.temporal.decode_pair`),
the input features except the plane fits and the sines (:func:`unwrap.learned.fast_features.make_inputs`),
and the decoding of the logits except the exponentials (:func:`unwrap.learned.fast_features.decode`).

Why: each of those is a dozen numpy passes over the frame (casts, masks, roundings, one temporary per
operation) and the channels interleaved for a channels-last forward in one more; the whole path
spent ~2x the forward around it (docs/speed.md, "Session 11: whole path"). Here each stage is one
or two passes that read every input once and write the network's input block in its final layout,
split into row ranges on two threads (every output pixel depends on its own inputs alone, so the
split does not change a bit). What numpy computes with its own vectorised approximations stays in
numpy so that nothing changes: the float32 ``sin`` / ``cos`` of the high phase and the float32
``exp`` of the decoding; the plane fits stay :mod:`unwrap.learned._plane_c` / numba's kernel.

Every other operation is a correctly rounded IEEE one (+, -, *, /, the float64 -> float32 cast, ceil,
fmod), written in numpy's order and with numpy's rules for ``remainder`` (``npy_divmod``), ``clip``
(``x > lo ? x : lo`` then ``x < hi ? x : hi``, NaN kept) and ``maximum`` (NaN kept), compiled
without fast-math and with ``-ffp-contract=off`` (:mod:`unwrap._native`). Each process checks the
library against the numpy code on small frames with holes, NaN, infinities, signed zeros and
padding before using it (:func:`_same_bits`), and the numpy code runs where they differ, where
there is no C compiler, or for what this does not cover (MW / NT, prior-free models, other
windows, non-float inputs): :func:`lib` is then None.

Integer arguments are ``int64_t`` on the C side and :class:`ctypes.c_int64` here (not ``long``:
32 bits on Windows).
"""
from __future__ import annotations

import math

import numpy as np

_SOURCE = r"""
#include <float.h>
#include <math.h>
#include <stdint.h>

typedef int64_t i64;

/* numpy's float64 remainder (npy_divmod): fmod, moved into the divisor's sign, +-0 -> the divisor's */
static inline double np_mod(double a, double b) {
    if (fabs(a) < b) return a < 0.0 ? a + b : a + 0.0;     /* b > 0: fmod(a, b) = a; -0.0 -> +0.0 */
    double m = fmod(a, b);
    if (m != 0.0) { if ((b < 0.0) != (m < 0.0)) m += b; }
    else m = copysign(0.0, b);
    return m;
}

/* numpy's clip of a float32: max(x, lo) then min(., hi), as x > lo ? x : lo (NaN kept) */
static inline float np_clip(float x, float lo, float hi) {
    float t = x != x ? x : (x > lo ? x : lo);
    return t != t ? t : (t < hi ? t : hi);
}

/* numpy's maximum of float32 (a >= b or a NaN: a; else b) */
static inline float np_max(float a, float b) { return (a >= b || a != a) ? a : b; }

/* decode_pair("mf"): rows y0 .. y1 - 1 of (H, W) maps */
void mf_prior(const double *plo, const double *phi, const unsigned char *valid, i64 W, i64 y0, i64 y1,
              double cut, double ratio, double two_pi, double half_tie, double kmax,
              double *prior, i64 *order, unsigned char *ok) {
    for (i64 i = y0 * W; i < y1 * W; i++) {
        double Phi = np_mod(plo[i] - cut, two_pi) + cut;
        double pr = (ratio * Phi - phi[i]) / two_pi;
        double k = ceil(pr - half_tie);
        int g = valid[i] && isfinite(pr);
        double kc = k > 0.0 ? k : 0.0;
        kc = kc < kmax ? kc : kmax;
        prior[i] = g ? pr : 0.0;
        order[i] = g ? (i64)kc : -1;
        ok[i] = (unsigned char)g;
    }
}

#define CH 512

/* make_inputs' first pass: the cleaned float32 maps, ok, the coarse phase (float64) and the channels
   that need neither the plane fits nor the sines: prior fraction, phase / pi, modulations, valid.
   X: channel c of pixel (y, x) at X[c * cs + (y * Wp + x) * ps]. In chunks of CH pixels of a row, one
   quantity at a time, so that the loops over pixels vectorise. */
void features1(const double *pr, const double *pl, const double *ph, const double *ml, const double *mh,
               const unsigned char *valid, i64 W, i64 y0, i64 y1, i64 Wp, i64 cs, i64 ps, float *X,
               i64 c_prior, i64 c_phase, i64 c_mod, i64 c_valid, float half, float pi32, float gain,
               double cut, double two_pi, float *ph32, unsigned char *ok, double *Phi) {
    float a[CH], b[CH], c[CH], d[CH], e[CH], v[CH];
    unsigned char slow[CH];
    for (i64 y = y0; y < y1; y++) {
        for (i64 x0 = 0; x0 < W; x0 += CH) {
            i64 n = W - x0 < CH ? W - x0 : CH, i = y * W + x0;
            for (i64 j = 0; j < n; j++) {
                /* as the torch batch: NaN -> 0; an infinity (also a float64 beyond float32's range) drops the pixel */
                float fa = (float)pr[i + j], fb = (float)pl[i + j], fc = (float)ph[i + j];
                float fd = (float)ml[i + j], fe = (float)mh[i + j];
                fa = fa != fa ? 0.0f : fa; fb = fb != fb ? 0.0f : fb; fc = fc != fc ? 0.0f : fc;
                fd = fd != fd ? 0.0f : fd; fe = fe != fe ? 0.0f : fe;
                int g = (valid[i + j] != 0) & (fabsf(fa) <= FLT_MAX) & (fabsf(fb) <= FLT_MAX) & (fabsf(fc) <= FLT_MAX)
                        & (fabsf(fd) <= FLT_MAX) & (fabsf(fe) <= FLT_MAX);
                a[j] = g ? fa : 0.0f; b[j] = g ? fb : 0.0f; c[j] = g ? fc : 0.0f;
                d[j] = g ? fd : 0.0f; e[j] = g ? fe : 0.0f; v[j] = g ? 1.0f : 0.0f;
            }
            for (i64 j = 0; j < n; j++) { ph32[i + j] = c[j]; ok[i + j] = (unsigned char)(v[j] != 0.0f); }
            int any_slow = 0;
            for (i64 j = 0; j < n; j++) {            /* np_mod's fast path; the rest below */
                double t = (double)b[j] - cut;
                int fast = fabs(t) < two_pi;
                double r = t < 0.0 ? t + two_pi : t + 0.0;
                Phi[i + j] = r + cut;
                slow[j] = (unsigned char)!fast;
                any_slow |= !fast;
            }
            if (any_slow)
                for (i64 j = 0; j < n; j++)
                    if (slow[j]) Phi[i + j] = np_mod((double)b[j] - cut, two_pi) + cut;
            for (i64 j = 0; j < n; j++) {
                float fr = a[j] - ceilf(a[j] - half);
                a[j] = fr * 2.0f;
                c[j] = c[j] / pi32;
                d[j] = np_clip(d[j] * gain, 0.0f, 2.0f);
                e[j] = np_clip(e[j] * gain, 0.0f, 2.0f);
            }
            float *xo = X + (y * Wp + x0) * ps;
            for (i64 j = 0; j < n; j++) {
                float *xj = xo + j * ps;
                xj[c_prior * cs] = a[j];
                xj[(c_phase + 2) * cs] = c[j];
                xj[c_mod * cs] = d[j];
                xj[(c_mod + 1) * cs] = e[j];
                xj[c_valid * cs] = v[j];
            }
        }
    }
}

/* make_inputs' second pass: per window w the smoothed prior's fraction and its disagreement with the
   traditional order from the plane fit P[w] of the coarse phase; the high phase's sine and cosine */
void features2(const double *const *P, i64 nw, const float *ph32, const float *sn, const float *cn,
               const i64 *trad, const unsigned char *ok, i64 W, i64 y0, i64 y1, i64 Wp, i64 cs, i64 ps,
               float *X, i64 c_smooth, i64 c_dis, i64 c_phase, double scale, double two_pi, float half) {
    float fr[8][CH], dis[8][CH], v[CH];
    for (i64 y = y0; y < y1; y++) {
        for (i64 x0 = 0; x0 < W; x0 += CH) {
            i64 n = W - x0 < CH ? W - x0 : CH, i = y * W + x0;
            for (i64 j = 0; j < n; j++) v[j] = ok[i + j] ? 1.0f : 0.0f;
            for (i64 w = 0; w < nw; w++) {
                const double *Pw = P[w] + i;
                for (i64 j = 0; j < n; j++) {
                    double p = Pw[j] * scale;
                    p = p - (double)ph32[i + j];
                    p = p / two_pi;
                    int g = ok[i + j] != 0;
                    float q = g ? (float)p : 0.0f;
                    float rs = ceilf(q - half);
                    float f = q - rs;
                    fr[w][j] = f * 2.0f;
                    float dd = rs - (float)trad[i + j];
                    dd = dd / 2.0f;
                    dd = np_clip(dd, -1.0f, 1.0f);
                    dis[w][j] = g ? dd : 0.0f;
                }
            }
            float *xo = X + (y * Wp + x0) * ps;
            for (i64 j = 0; j < n; j++) {
                float *xj = xo + j * ps;
                for (i64 w = 0; w < nw; w++) {
                    xj[(c_smooth + w) * cs] = fr[w][j];
                    xj[(c_dis + w) * cs] = dis[w][j];
                }
                xj[c_phase * cs] = sn[i + j] * v[j];
                xj[(c_phase + 1) * cs] = cn[i + j] * v[j];
            }
        }
    }
}

/* decode, first pass: D[k] = z_k - max_k z_k (planar K x H x W) from logits Z (element strides); in
   chunks of CH columns, class by class, so that the loops over pixels vectorise */
void decode1(const float *Z, i64 K, i64 sk, i64 sy, i64 sx, i64 W, i64 y0, i64 y1, i64 HW, float *D) {
    float m[CH];
    for (i64 y = y0; y < y1; y++) {
        for (i64 x0 = 0; x0 < W; x0 += CH) {
            i64 n = W - x0 < CH ? W - x0 : CH;
            const float *z = Z + y * sy + x0 * sx;
            for (i64 j = 0; j < n; j++) m[j] = z[j * sx];
            for (i64 k = 1; k < K; k++) {
                const float *zk = z + k * sk;
                for (i64 j = 0; j < n; j++) m[j] = np_max(m[j], zk[j * sx]);
            }
            for (i64 k = 0; k < K; k++) {
                const float *zk = z + k * sk;
                float *d = D + k * HW + y * W + x0;
                for (i64 j = 0; j < n; j++) d[j] = zk[j * sx] - m[j];
            }
        }
    }
}

/* decode, second pass: the softmax probability of the first most probable class, the order (chunks of
   CH pixels, class by class, as the numpy code runs over whole planes) */
void decode2(const float *E, i64 K, i64 HW, i64 i0, i64 i1, const i64 *trad, const unsigned char *ok, i64 physics,
             i64 shift, i64 kmax, i64 *order, float *conf) {
    float s[CH], c[CH];
    i64 cls[CH];
    for (i64 a = i0; a < i1; a += CH) {
        i64 n = i1 - a < CH ? i1 - a : CH;
        const float *e0 = E + a;
        for (i64 j = 0; j < n; j++) s[j] = e0[j];
        for (i64 k = 1; k < K; k++) {
            const float *ek = E + k * HW + a;
            for (i64 j = 0; j < n; j++) s[j] = s[j] + ek[j];
        }
        for (i64 j = 0; j < n; j++) { c[j] = e0[j] / s[j]; cls[j] = 0; }
        for (i64 k = 1; k < K; k++) {
            const float *ek = E + k * HW + a;
            for (i64 j = 0; j < n; j++) {
                float pk = ek[j] / s[j];
                cls[j] = pk > c[j] ? k : cls[j];
                c[j] = np_max(c[j], pk);
            }
        }
        for (i64 j = 0; j < n; j++) {
            i64 o = physics ? trad[a + j] + cls[j] - shift : cls[j];
            o = o > 0 ? o : 0;
            o = o < kmax ? o : kmax;
            order[a + j] = ok[a + j] ? o : -1;
            conf[a + j] = ok[a + j] ? c[j] : 0.0f;
        }
    }
}
"""

_LIB: list = []
#: most smoothing windows the C code takes (``features2``'s row buffers)
MAX_WINDOWS = 8
#: rows below which a stage runs as one call (threads cost more than they save)
SPLIT_MIN_PIX = 1 << 15


def _bind(dll, reference):
    """The typed functions of ``dll`` if they give the numpy code's bits (:func:`_same_bits`), else None."""
    import ctypes

    p, i, d, f = ctypes.c_void_p, ctypes.c_int64, ctypes.c_double, ctypes.c_float
    sig = {"mf_prior": [p, p, p, i, i, i, d, d, d, d, d, p, p, p],
           "features1": [p, p, p, p, p, p, i, i, i, i, i, i, p, i, i, i, i, f, f, f, d, d, p, p, p],
           "features2": [p, i, p, p, p, p, p, i, i, i, i, i, i, p, i, i, i, d, d, f],
           "decode1": [p, i, i, i, i, i, i, i, i, p],
           "decode2": [p, i, i, i, i, p, p, i, i, i, p, p]}
    funcs = {}
    for name, args in sig.items():
        fn = getattr(dll, name)         # AttributeError: not this library (build: None)
        fn.argtypes, fn.restype = args, None
        funcs[name] = fn
    return funcs if _same_bits(funcs, reference) else None


def lib(reference):
    """The checked library's functions (module docstring), or None. ``reference``: the module whose
    numpy code the library replicates, :mod:`unwrap.learned.fast_features` (passed in, so that
    this module imports nothing of it: :func:`unwrap.learned.fast_features.native_features`)."""
    if not _LIB:
        from .._native import build

        got = build("learned_features", _SOURCE, lambda dll: _bind(dll, reference))
        _LIB.append(got)
    return _LIB[0]


def _rows(H: int, W: int, fn) -> None:
    """``fn(y0, y1)`` over rows 0 .. H - 1, in two ranges on the package's thread pool when the frame
    is large (ctypes releases the GIL)."""
    if H * W < SPLIT_MIN_PIX or H < 2:
        fn(0, H)
        return
    from .._threads import pool

    mid = H // 2
    fut = pool("learned-features").submit(fn, mid, H)
    fn(0, mid)
    fut.result()


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def covered(*arrays) -> bool:
    """Whether the arrays' dtypes are ones whose float32 rounding this library reproduces: float64
    (rounded once) or float32 / float16 (exact in float64); numpy's cast of an integer to float32
    may round differently from a cast through float64."""
    return all(np.asarray(a).dtype.kind == "f" and np.asarray(a).dtype.itemsize <= 8 for a in arrays)


def integral(order) -> bool:
    """Whether ``order`` (the traditional orders) holds integers that int64 holds exactly (what the
    library reads them as; float orders keep the numpy code, which rounds them to float32 directly)."""
    d = np.asarray(order).dtype
    return d.kind == "i" or (d.kind == "u" and d.itemsize < 8)


def mf_prior(phi_lo, phi_hi, valid, f_lo: float, f_hi: float, width, F):
    """:func:`unwrap.temporal.decode_pair` ``("mf", nan_to_num(phi_lo), nan_to_num(phi_hi), ...)``:
    (prior float64 (H, W) 0 where invalid, order int64 -1 invalid, valid bool), the same bits.
    ``valid`` must already exclude non-finite phases (as :func:`unwrap.learned.infer.unwrap_learned`'s
    does): the values of invalid pixels are not read. ``F``: :func:`lib`'s functions."""
    from .._xp import TIE_BAND, TWO_PI
    from ..temporal import base_cut, check_mf_ladder

    fn = F["mf_prior"]
    f = check_mf_ladder((f_lo, f_hi))                  # raises as mf_unwrap would
    cut = base_cut(float(f[0]), width)
    plo, phi = _f64(phi_lo), _f64(phi_hi)
    ok_in = np.ascontiguousarray(valid, dtype=bool)
    if plo.shape != phi.shape or ok_in.shape != phi.shape or phi.ndim != 2:
        raise ValueError(f"phases {plo.shape}, {phi.shape} and valid {ok_in.shape}: expected one (H, W) shape")
    H, W = phi.shape
    prior, order, ok = np.empty((H, W)), np.empty((H, W), np.int64), np.empty((H, W), bool)
    kmax = float(math.floor(float(f[1]) + 0.5))
    ratio = float(f[1] / f[0])
    _rows(H, W, lambda y0, y1: fn(plo.ctypes.data, phi.ctypes.data, ok_in.ctypes.data, W, y0, y1, cut, ratio,
                                  TWO_PI, 0.5 + TIE_BAND, kmax, prior.ctypes.data, order.ctypes.data, ok.ctypes.data))
    return prior, order, ok


def _strides(x: np.ndarray) -> tuple[int, int]:
    """(channel stride, pixel stride) in elements of ``x`` (1, C, Hp, Wp), a view of NCHW or NHWC memory."""
    s = x.strides
    return s[1] // 4, s[3] // 4


def make_inputs(prior, phase_low, phase_high, modulation_low, modulation_high, order_traditional, valid,
                frequencies, windows, *, layout: str, multiple: int, plane_filters, coarse, F):
    """:func:`unwrap.learned.fast_features.make_inputs` of a physics-aware model on an MF pair
    (arguments as there; ``plane_filters(Phi, ok, windows)``: the plane fits,
    :func:`unwrap.learned.fast_features.plane_filter`; ``coarse``: (coarse frequency, cut) of the MF
    pair, :func:`unwrap.learned.fast_features.coarse_cut`): (x (1, C, H', W') float32, ok (H, W)
    bool), the same bits. Float inputs only (:func:`covered`)."""
    from .._xp import TIE_BAND, TWO_PI
    from .channels import MODULATION_GAIN, channel_slices
    if len(windows) > MAX_WINDOWS:   # features2 keeps a fixed array of row buffers
        raise ValueError(f"_features_c.make_inputs: at most {MAX_WINDOWS} smoothing windows, got {len(windows)}")
    at = channel_slices("physics", windows)
    C = max(s.stop for s in at.values())
    pr, pl, ph, ml, mh = (_f64(a) for a in (prior, phase_low, phase_high, modulation_low, modulation_high))
    valid = np.ascontiguousarray(valid, dtype=bool)
    trad = np.ascontiguousarray(order_traditional, dtype=np.int64)
    H, W = ph.shape
    m = max(int(multiple), 1)
    Hp, Wp = H + (-H) % m, W + (-W) % m
    alloc = np.zeros if (Hp, Wp) != (H, W) else np.empty
    if layout == "nhwc":
        x = alloc((1, Hp, Wp, C), dtype=np.float32).transpose(0, 3, 1, 2)
    else:
        x = alloc((1, C, Hp, Wp), dtype=np.float32)
    cs, ps = _strides(x)
    half = np.float32(0.5 + TIE_BAND)
    f_l, f_h = (float(f) for f in frequencies)
    f_c, cut = (float(c) for c in coarse)
    ph32, ok, Phi = np.empty((H, W), np.float32), np.empty((H, W), bool), np.empty((H, W))
    xp = x.ctypes.data
    F1 = F["features1"]
    _rows(H, W, lambda y0, y1: F1(pr.ctypes.data, pl.ctypes.data, ph.ctypes.data, ml.ctypes.data, mh.ctypes.data,
                                  valid.ctypes.data, W, y0, y1, Wp, cs, ps, xp, at["prior"].start,
                                  at["phase_high"].start, at["modulation"].start, at["valid"].start, half,
                                  np.float32(math.pi), np.float32(MODULATION_GAIN), cut, TWO_PI, ph32.ctypes.data,
                                  ok.ctypes.data, Phi.ctypes.data))
    sn, cn = np.sin(ph32), np.cos(ph32)
    filt = plane_filters(Phi, ok, windows)
    planes = [np.ascontiguousarray(filt[int(w) | 1], dtype=np.float64) for w in windows]
    import ctypes

    ptrs = (ctypes.c_void_p * len(planes))(*[q.ctypes.data for q in planes])
    F2 = F["features2"]
    _rows(H, W, lambda y0, y1: F2(ctypes.cast(ptrs, ctypes.c_void_p), len(planes), ph32.ctypes.data, sn.ctypes.data,
                                  cn.ctypes.data, trad.ctypes.data, ok.ctypes.data, W, y0, y1, Wp, cs, ps, xp,
                                  at["smoothed"].start, at["disagreement"].start, at["phase_high"].start,
                                  f_h / f_c, TWO_PI, half))
    return x, ok


def decode(logits, order_traditional, ok, f_high: float, kind: str, max_correction: int, F):
    """:func:`unwrap.learned.fast_features.decode` without ``wrap_orders`` of float32 logits (1, K, H, W)
    in any memory layout: (order int64 (H, W), confidence float32 (H, W)), the same bits."""
    z = np.asarray(logits)[0]
    K, H, W = z.shape
    sk, sy, sx = (s // 4 for s in z.strides)
    trad = np.ascontiguousarray(order_traditional, dtype=np.int64)
    okc = np.ascontiguousarray(ok, dtype=bool)
    D = np.empty((K, H, W), np.float32)
    _rows(H, W, lambda y0, y1: F["decode1"](z.ctypes.data, K, sk, sy, sx, W, y0, y1, H * W, D.ctypes.data))
    np.exp(D, out=D)
    order, conf = np.empty((H, W), np.int64), np.empty((H, W), np.float32)
    kmax = int(math.floor(float(f_high) + 0.5))
    phys = 1 if kind == "physics" else 0
    _rows(H, W, lambda y0, y1: F["decode2"](D.ctypes.data, K, H * W, y0 * W, y1 * W, trad.ctypes.data,
                                            okc.ctypes.data, phys, int(max_correction), kmax, order.ctypes.data,
                                            conf.ctypes.data))
    return order, conf


#: (seed, H, W) of the frames :func:`_same_bits` runs: a small one, and rows wider than the C loops'
#: chunk of 512 pixels (so a chunk boundary falls inside a row, and the decoding's flat range crosses it)
CHECK_FRAMES = ((0, 21, 19), (1, 5, 530))


def _check_frame(seed: int, H: int = 21, W: int = 19):
    """A small MF frame with holes, NaN, infinities, signed zeros, huge values, negative and large
    modulations, and priors near rounding boundaries (what :func:`_same_bits` runs)."""
    rng = np.random.default_rng(seed)
    plo = rng.uniform(-math.pi, math.pi, (H, W))
    phi = rng.uniform(-math.pi, math.pi, (H, W))
    ml, mh = rng.uniform(-0.1, 0.7, (H, W)), rng.uniform(-0.1, 0.7, (H, W)).astype(np.float32)
    valid = rng.random((H, W)) > 0.15
    plo[0, :4] = [np.nan, np.inf, -0.0, 0.0]
    phi[1, :4] = [-np.inf, np.nan, -0.0, 1e300]
    ml[2, :5] = [np.nan, -0.0, 0.0, 1e39, -np.inf]
    mh[3, :3] = [np.inf, -0.0, np.nan]
    return plo, phi, ml, mh, valid


def _same_bits(F, FF) -> bool:
    """Whether the library gives the numpy code's bits (module docstring): the pair's decode, the
    features in both layouts with and without padding, the decoding of both model kinds in both
    layouts, on :data:`CHECK_FRAMES` (~4 ms once per process; tests/test_learned_whole_path.py covers more,
    the two threads' split of a large frame included)."""
    with np.errstate(over="ignore", invalid="ignore"):       # the frame's float64 beyond float32's range
        return _same_bits_on_frames(F, FF)


def _same_bits_on_frames(F, FF) -> bool:
    from ..temporal import decode_pair

    for seed, H, W in CHECK_FRAMES:
        plo, phi, ml, mh, valid = _check_frame(seed, H, W)
        v = valid & np.isfinite(plo) & np.isfinite(phi)
        want = decode_pair("mf", np.nan_to_num(plo), np.nan_to_num(phi), 1.0, 16.0, 40.0, v)
        got = mf_prior(plo, phi, v, 1.0, 16.0, 40.0, F)
        if any(a.tobytes() != b.tobytes() for a, b in zip(want, got)):
            return False
        prior, trad, ok = want
        prior = prior.copy()
        prior[4, :3] = [np.nan, 0.5, -0.5]
        for layout, mult in (("nchw", 1), ("nhwc", 16)):
            a = FF.make_inputs("physics", "mf", prior, plo, phi, ml, mh, trad, ok, (1.0, 16.0), layout=layout,
                               multiple=mult, native=False)
            b = make_inputs(prior, plo, phi, ml, mh, trad, ok, (1.0, 16.0), FF.SMOOTH_WINDOWS, layout=layout,
                            multiple=mult, plane_filters=FF.plane_filter,
                            coarse=FF.coarse_cut("mf", 1.0, 16.0), F=F)
            if a[1].tobytes() != b[1].tobytes() or a[0].shape != b[0].shape or not np.array_equal(
                    a[0].view(np.uint32), b[0].view(np.uint32)):
                return False
        rng = np.random.default_rng(seed)
        z = rng.normal(0.0, 3.0, (1, 5, H, W)).astype(np.float32)
        z[0, :, 0, 0] = 1.0                             # ties: the first class wins
        z[0, 2, 1, 1] = np.nan
        for logits, kinds in ((z, ("prior_free",)),
                              (np.ascontiguousarray(z.transpose(0, 2, 3, 1)).transpose(0, 3, 1, 2)[..., :H - 1, :W - 1],
                               ("physics",))):
            t, k = trad[:logits.shape[2], :logits.shape[3]], ok[:logits.shape[2], :logits.shape[3]]
            for kind in kinds:
                a = FF.decode(logits, t, k, 16.0, kind, 2, None, native=False)
                b = decode(logits, t, k, 16.0, kind, 2, F)
                if any(x.tobytes() != y.tobytes() for x, y in zip(a, b)):
                    return False
    return True
