"""The network's inputs and the decoding of its outputs for ONE frame, in numpy (no torch): what
inference runs (torch or onnxruntime); training keeps :mod:`unwrap.learned.features`.

The same quantities as :func:`unwrap.learned.features.make_inputs` / :func:`~unwrap.learned.features.decode`
(channel table there), computed in one pass:

- the local plane fits of the coarse phase at each box (:data:`channels.SMOOTH_WINDOWS`, 7 and
  15 px): two separable sliding passes per box, moments about each box's centre, the plane solved
  by Cramer's rule with :func:`unwrap.learned.smoothing.smooth_phase`'s conditioning rule, run by
  numba's compiled kernel (:mod:`unwrap.learned._plane_kernel`) in a process that has loaded it,
  else by its C or numpy replica (:mod:`unwrap.learned._plane_c`, :mod:`unwrap.learned._plane_numpy`:
  bitwise the same result, without numba's ~1 s and ~120 MB of start-up; :func:`_kernel`);
- every other channel is elementwise float32, in the order and precision of the torch code (the
  phases are rounded to float32 before the float64 plane fit, as the torch batch holds them).

The result agrees with the torch features within float rounding (sums accumulated in another
order: ~1e-12 rad on the filtered phase); an order can differ only where a smoothed
prior sits within that rounding of a rounding boundary (a float32 tie; counted by the tests).

Shapes: phases / modulations (H, W); inputs (1, C, H, W) float32, C-contiguous or, for a
channels-last forward, a view of a (1, H, W, C) block (``layout="nhwc"``); logits (1, K, H, W) any
float dtype, either memory layout.

SYNOPSIS

    >>> import numpy as np
    >>> from unwrap.learned.fast_features import plane_filter
    >>> y, x = np.mgrid[0:20, 0:30].astype(float)
    >>> Phi = 0.01 * x + 0.02 * y
    >>> out = plane_filter(Phi, x < 12, (7,))[7]
    >>> bool(np.allclose(out[x < 12], Phi[x < 12]))       # exact on a plane, even at the edge
    True
"""
from __future__ import annotations

import math

import numpy as np

from .._xp import TIE_BAND, wrap
from . import beat_window as BW
from .channels import METHOD_INDEX, MODULATION_GAIN, SMOOTH_WINDOWS, channel_slices

_F32 = np.float32


def _round_order32(x: np.ndarray) -> np.ndarray:
    """unwrap's rounding (ties down) in float32, as torch computes it on a float32 tensor."""
    return np.ceil(x - _F32(0.5 + TIE_BAND))


def box_sum(stack: np.ndarray, window: int) -> np.ndarray:
    """Sum over the ``window`` x ``window`` box centred on each pixel, zeros outside the image.

    ``stack``: (H, W) or (H, W, C) float64 (C <= 512); same shape out. Separable running sums
    (``cv2.boxFilter``), float64 throughout."""
    import cv2

    return cv2.boxFilter(stack, cv2.CV_64F, (window, window), normalize=False, borderType=cv2.BORDER_CONSTANT)


def plane_filter(Phi: np.ndarray, valid: np.ndarray, windows=SMOOTH_WINDOWS, fit: str = "plane") -> dict:
    """{window: filtered ``Phi`` (H, W) float64} over the valid pixels of each box; invalid pixels
    keep ``Phi``. ``fit``: "plane" (local least-squares plane at the pixel; the box mean where the
    box has < 3 valid pixels or they are collinear) or "mean" (masked box mean).
    Same algorithm and conditioning rule as :func:`unwrap.learned.smoothing.smooth_phase`;
    "plane" by numba's compiled kernel (:mod:`unwrap.learned._plane_kernel`) or its bitwise C or
    numpy replica (:func:`_kernel`); "mean" as box sums."""
    if fit not in ("plane", "mean"):
        raise ValueError(f"fit {fit!r}: expected 'plane' or 'mean'")
    Phi = np.asarray(Phi, dtype=np.float64)
    if fit == "plane":
        kernel = _kernel()
        ok = np.ascontiguousarray(valid, dtype=bool)
        Phi = np.ascontiguousarray(Phi)
        sizes = [int(w) | 1 for w in windows]
        if len(sizes) > 1 and Phi.size >= THREAD_MIN_PIX and getattr(kernel, "one_thread", False):
            # the one-thread C kernel: the boxes side by side on the package's pool (ctypes releases
            # the GIL; each box is computed alone, so the bits do not change)
            from .._threads import pool

            later = [pool("plane-fit").submit(kernel, Phi, ok, s // 2) for s in sizes[1:]]
            first = kernel(Phi, ok, sizes[0] // 2)
            return dict(zip(sizes, [first, *(f.result() for f in later)]))
        return {s: kernel(Phi, ok, s // 2) for s in sizes}
    v = np.asarray(valid, dtype=bool).astype(np.float64)
    P = np.where(v > 0, Phi, 0.0)
    stack = np.stack([v, P], axis=-1)
    out = {}
    for win in windows:
        s = box_sum(stack, int(win) | 1)
        S0, SP = s[..., 0], s[..., 1]
        out[int(win) | 1] = np.where(v > 0, np.where(S0 > 0.5, SP / np.maximum(S0, 1.0), P), Phi)
    return out


#: Pixels from which :func:`plane_filter` runs the C kernel's boxes on two threads.
THREAD_MIN_PIX = 1 << 15


def native_features():
    """The C replica of this module's MF features and decoding and of the pair's decode
    (:mod:`unwrap.learned._features_c`): its functions, built once per machine and checked against
    this module's numpy code once per process; None where there is no C compiler or the bits differ."""
    import sys

    from . import _features_c as FC

    return FC.lib(sys.modules[__name__])


def native_plane_filter() -> bool:
    """True when the plane fits run compiled without numba here (the C replica built or cached):
    then even a batch of captures has no use for numba's ~1 s start-up (a box takes ~17 ms in C,
    ~10 ms in numba, ~0.1 s in numpy at 900 x 700)."""
    from ._plane_c import kernel

    return kernel() is not None


def _kernel():
    """The one-box plane filter ``f(Phi, valid, r)``: numba's compiled kernel
    (:mod:`unwrap.learned._plane_kernel`) in a process that has imported numba already (the
    traditional decoders' fused kernel, a batch's warm-up: :func:`unwrap.warmup.plane_filter`,
    waited for here), else its C replica (:mod:`unwrap.learned._plane_c`, compiled once per machine
    and cached), else, without a C compiler, its numpy replica (:mod:`unwrap.learned._plane_numpy`);
    all three give the same bits. ``calib unwrap --model`` on one capture so never imports numba,
    whose import and cache load cost ~0.8-1 s of CPU and ~120 MB resident (docs/speed.md, session
    9); a box at 900 x 700 takes ~10 ms compiled, ~17 ms in C, ~0.1 s in numpy."""
    import sys

    from .. import warmup

    w = warmup.started("plane_filter")
    if w is not None:
        w.wait()
    if "numba" in sys.modules:
        try:
            from ._plane_kernel import plane_filter_kernel
            return plane_filter_kernel
        except ImportError:
            pass
    from ._plane_c import kernel

    c = kernel()
    if c is not None:
        return c
    from ._plane_numpy import plane_filter_numpy
    return plane_filter_numpy


def coarse_phase(method: str, phi_l: np.ndarray, phi_h: np.ndarray, f_l: float, f_h: float, width=None):
    """(absolute coarse phase (H, W) float64, coarse frequency, usable): MF the unit phase, MW / NT
    the beat of the pair (absolute only when ``f_h - f_l <= 1``, else ``usable`` is False), cut
    at 2 pi as :func:`unwrap.learned.smoothing.smoothed_prior` cuts it."""
    is_mf = method == "mf"
    usable = is_mf or f_h - f_l <= 1.0 + 1e-9
    f_c, cut = coarse_cut(method, f_l, f_h, width)
    coarse = phi_l if is_mf else wrap(phi_h - phi_l)
    Phi = _remainder_2pi(coarse - cut)
    Phi += cut
    return Phi, f_c, usable


def _remainder_2pi(x: np.ndarray) -> np.ndarray:
    """``np.remainder(x, 2 pi)`` of float64 ``x``, the same bits, without its slow general path
    where every ``x`` lies in (-2 pi, 2 pi) (a wrapped phase minus the cut): there numpy's divmod
    returns ``x`` for ``x >= 0`` and ``x + 2 pi`` (one rounding) below. Anything else (larger,
    NaN, infinite): ``np.remainder`` itself."""
    two_pi = 2 * math.pi
    x = np.asarray(x, dtype=np.float64)
    neg = x < 0
    out = x + two_pi
    np.add(x, 0.0, out=out, where=~neg)      # x itself, but -0.0 -> +0.0 as numpy's remainder gives
    if not (np.abs(x) < two_pi).all():       # also False on NaN
        return np.remainder(x, two_pi)
    return out


def coarse_cut(method: str, f_l: float, f_h: float, width=None) -> tuple[float, float]:
    """(coarse frequency, cut (rad)) of :func:`coarse_phase`: the coarse phase lies in [cut, cut + 2 pi)."""
    from ..temporal import edge_fraction

    f_c = min(f_l if method == "mf" else f_h - f_l, 1.0)
    return f_c, min(-math.pi * (1.0 - f_c), -2 * math.pi * f_c * edge_fraction(width))


def smoothed_priors(method: str, phi_l, phi_h, f_l: float, f_h: float, valid, windows=SMOOTH_WINDOWS,
                    fit: str = "plane", width=None):
    """({window: prior (H, W) float64 with the coarse phase plane-filtered}, usable): the high
    frequency's prior from the filtered coarse phase (one plane fit per window: :func:`plane_filter`). MW /
    NT: the beat is filtered as a periodic phase (:func:`unwrap.learned.beat_window.circular_plane_filter`)."""
    phi_l, phi_h = np.asarray(phi_l, np.float64), np.asarray(phi_h, np.float64)
    Phi, f_c, usable = coarse_phase(method, phi_l, phi_h, float(f_l), float(f_h), width)
    if method == "mf":
        filt = plane_filter(Phi, valid, windows, fit)
    else:       # the beat may wrap inside the image (a pair declared on its common window)
        filt = BW.circular_plane_filter(Phi, valid, coarse_cut(method, f_l, f_h, width)[1], windows, plane_filter, fit)
    out = {}
    for w, Ps in filt.items():      # (f_h / f_c * Ps - phi_h) / (2 pi), in place (the fit's map is ours)
        Ps *= float(f_h) / f_c
        Ps -= phi_h
        Ps /= 2 * math.pi
        out[w] = Ps
    return out, usable


def make_inputs(kind: str, method: str, prior, phase_low, phase_high, modulation_low, modulation_high,
                order_traditional, valid, frequencies, windows=SMOOTH_WINDOWS, *, layout: str = "nchw",
                multiple: int = 1, native: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(x (1, C, H', W') float32, ok (H, W) bool): the network input of one frame, channels as
    :func:`unwrap.learned.channels.channel_slices` (``windows``: the smoothing boxes, px).

    ARGUMENTS as the torch batch of :func:`unwrap.learned.infer.unwrap_learned`: prior, wrapped phases
    (rad) and modulations (fraction of full scale) (H, W), NaN allowed where not valid;
    order_traditional (H, W) int; valid (H, W) bool; frequencies (low, high).
    ``ok``: ``valid`` and every input finite.

    ``layout``: "nchw" (x C-contiguous) or "nhwc" (x a (1, C, H', W') view of a C-contiguous
    (1, H', W', C) block: what a channels-last forward takes without a conversion; the same
    values). ``multiple``: H' and W' rounded up to a multiple of it, the extra rows and columns
    zero (= invalid; the network's own padding, done here without a copy of the input).
    ``native``: a physics-aware model on an MF pair of float maps runs the C replica of this code
    (:mod:`unwrap.learned._features_c`: the same bits, ~3x faster) where it is built and checked;
    False: this numpy code always."""
    if layout not in LAYOUTS:
        raise ValueError(f"layout {layout!r}: expected one of {LAYOUTS}")
    valid = np.asarray(valid, dtype=bool)
    at = channel_slices(kind, windows)          # raises on an unknown kind
    if native and kind == "physics" and method == "mf" and len(windows) <= 8:
        from . import _features_c as FC

        maps = (prior, phase_low, phase_high, modulation_low, modulation_high)
        if FC.covered(*maps) and FC.integral(order_traditional) and np.ndim(phase_high) == 2 \
                and all(np.shape(a) == valid.shape for a in (*maps, order_traditional)) and native_features():
            return FC.make_inputs(*maps, order_traditional, valid, frequencies, windows, layout=layout,
                                  multiple=multiple, plane_filters=plane_filter,
                                  coarse=coarse_cut("mf", *map(float, frequencies)), F=native_features())

    def f32(a):
        # the torch batch's map: NaN -> 0 and every value outside ``valid`` 0, rounded to float32
        # (+-inf stays infinite, so ``ok`` drops it, as nan_to_num's +-1.8e308 did once rounded)
        a = np.asarray(a)
        out = a.astype(_F32)                   # NaN and +-inf survive the rounding, so test after it
        np.copyto(out, zero, where=~(valid & (out == out)))
        return out

    zero = _F32(0.0)
    pr, pl, ph, ml, mh = (f32(a) for a in (prior, phase_low, phase_high, modulation_low, modulation_high))
    ok = valid & np.isfinite(pr) & np.isfinite(pl) & np.isfinite(ph) & np.isfinite(ml) & np.isfinite(mh)
    v = ok.astype(_F32)
    bad = ~ok
    for a in (pr, pl, ph, ml, mh):               # clean: 0 where not ok, in place (the maps are ours)
        np.copyto(a, zero, where=bad)
    C = max(s.stop for s in at.values())
    H, W = ok.shape
    m = max(int(multiple), 1)
    Hp, Wp = H + (-H) % m, W + (-W) % m
    # channels written in place, no stacking copy; the padding (if any) stays zero
    x = (np.zeros if (Hp, Wp) != (H, W) else np.empty)((1, C, Hp, Wp), dtype=_F32)
    X = x[0, :, :H, :W]
    phi_h = ph
    if kind == "physics":
        _prior_channels(X, at, method, pr, pl, ph, order_traditional, ok, frequencies, windows)
    else:
        c = at["phase_low"].start
        np.multiply(np.sin(pl), v, out=X[c])
        np.multiply(np.cos(pl), v, out=X[c + 1])
        np.divide(pl, _F32(math.pi), out=X[c + 2])
        c = at["method"].start
        for i in range(at["method"].stop - c):      # the method's one-hot
            X[c + i] = v * _F32(METHOD_INDEX[method] == i)
    c = at["phase_high"].start
    np.multiply(np.sin(phi_h), v, out=X[c])
    np.multiply(np.cos(phi_h), v, out=X[c + 1])
    np.divide(phi_h, _F32(math.pi), out=X[c + 2])
    for j, m in enumerate((ml, mh)):
        m *= _F32(MODULATION_GAIN)
        np.clip(m, zero, _F32(2.0), out=X[at["modulation"].start + j])
    X[at["valid"].start] = v
    if layout == "nhwc":
        x = to_nhwc(x)
    return x, ok


def _prior_channels(X, at, method, p, pl, ph, order_traditional, ok, frequencies, windows) -> None:
    """The physics-aware model's prior channels of :func:`make_inputs`, written into ``X`` (C, H, W):
    the prior's fraction, and per window the smoothed prior's fraction and its disagreement with
    the traditional order (``p``, ``pl``, ``ph``: the cleaned float32 prior and phases)."""
    zero, bad = _F32(0.0), ~ok
    c = at["prior"].start
    np.subtract(p, _round_order32(p), out=X[c])
    X[c] *= _F32(2.0)
    trad = np.asarray(order_traditional).astype(_F32)
    f_l, f_h = (float(f) for f in frequencies)
    priors, usable = smoothed_priors(method, pl.astype(np.float64), ph.astype(np.float64), f_l, f_h, ok, windows)
    period = BW.wrap_orders(method, f_l, f_h) if usable else None
    for i, w in enumerate(windows):
        s, d = at["smoothed"].start + i, at["disagreement"].start + i
        ps = (priors[int(w) | 1] if usable else p.astype(np.float64)).astype(_F32)
        if period:              # on the traditional order's window (the beat may wrap in the image)
            ps = BW.nearest_branch(ps, trad, period)
        ps[bad] = zero
        rs = _round_order32(ps)
        np.subtract(ps, rs, out=X[s])
        X[s] *= _F32(2.0)
        if usable:
            rs -= trad
            rs /= _F32(2.0)
            np.clip(rs, _F32(-1.0), _F32(1.0), out=X[d])
            X[d][bad] = zero
        else:
            X[d] = zero


#: Memory layouts of :func:`make_inputs`' result (both index as (1, C, H, W)).
LAYOUTS = ("nchw", "nhwc")


def to_nhwc(x: np.ndarray) -> np.ndarray:
    """``x`` (1, C, H, W) as a (1, C, H, W) view of a C-contiguous (1, H, W, C) block (the same
    values): one interleaving pass (``cv2.merge``, ~3x the cost of writing the planes, a third of
    torch's own conversion), or a no-op where ``x`` is already so laid out."""
    if is_nhwc(x):
        return x
    C = x.shape[1]
    if x.dtype == _F32 and C <= 512:
        import cv2

        planes = [np.ascontiguousarray(x[0, c]) for c in range(C)]
        hwc = cv2.merge(planes) if C > 1 else planes[0][..., None]
        return hwc.reshape(1, *hwc.shape[:2], C).transpose(0, 3, 1, 2)
    return np.ascontiguousarray(x.transpose(0, 2, 3, 1)).transpose(0, 3, 1, 2)


def is_nhwc(x: np.ndarray) -> bool:
    """Whether ``x`` (1, C, H, W) is a view of a C-contiguous (1, H, W, C) block."""
    return x.ndim == 4 and x.transpose(0, 2, 3, 1).flags.c_contiguous


def class_planes(logits: np.ndarray) -> list:
    """The K class planes (H, W) float32 C-contiguous of logits (1, K, H, W) in any memory layout:
    views where each plane is already contiguous (NCHW), else one de-interleaving pass
    (``cv2.split`` of the (H, W, K) channels-last block a channels-last forward returns)."""
    z = np.asarray(logits)[0]
    if z.dtype == _F32 and all(z[k].flags.c_contiguous for k in range(z.shape[0])):
        return [z[k] for k in range(z.shape[0])]
    hwk = z.transpose(1, 2, 0)      # rows may be strided (a crop of a padded frame): cv2 takes them
    if z.dtype == _F32 and hwk.strides[1:] == (4 * z.shape[0], 4) and hwk.strides[0] > 0 and z.shape[0] <= 512:
        import cv2

        return list(cv2.split(hwk))
    return [np.ascontiguousarray(z[k], dtype=_F32) for k in range(z.shape[0])]


def decode(logits: np.ndarray, order_traditional, ok, f_high: float, kind: str, max_correction: int = 2,
           wrap_orders=None, *, native: bool = True):
    """Logits (1, K, H, W) -> (order int64 (H, W), -1 where not ``ok``; confidence float32 (H, W)).

    physics: the most probable correction added to the traditional order, clipped to
    [0, round(f_high)] (``wrap_orders``, the orders of one coarse period: taken modulo it first,
    :func:`unwrap.learned.beat_window.modulo_orders`); prior_free: the most probable order class.
    Confidence: its softmax probability (float32, 0 where not ok).

    ``logits`` in either memory layout (NCHW or the channels-last forward's; :func:`class_planes`).
    Class by class on (H, W) planes, the same float32 operations in the same order as a softmax
    over the class axis then its first argmax (``max``, ``exp(z - max)``, the sum from class 0
    up, the division): the same bits, without numpy's slow reductions along a strided axis.
    ``native``: float32 logits without ``wrap_orders`` are decoded by the C replica of this code
    (:mod:`unwrap.learned._features_c`, the same bits) where it is built and checked."""
    if native and not wrap_orders and np.asarray(logits).dtype == _F32 and np.ndim(logits) == 4:
        from . import _features_c as FC

        hw = np.shape(logits)[2:]       # the C code reads (H, W) of each: other shapes are numpy's to refuse
        if np.shape(ok) == hw and np.shape(order_traditional) == hw and native_features():
            return FC.decode(logits, order_traditional, ok, f_high, kind, max_correction, native_features())
    zs = class_planes(logits)
    zmax = zs[0].copy()
    for z in zs[1:]:
        np.maximum(zmax, z, out=zmax)
    e = [np.exp(z - zmax) for z in zs]
    s = e[0].copy()
    for ek in e[1:]:
        s += ek
    conf = e[0] / s
    cls = np.zeros(s.shape, dtype=np.int64)
    for k in range(1, len(e)):              # the first class of the largest probability, as argmax picks it
        pk = np.divide(e[k], s, out=e[k])
        better = pk > conf
        cls[better] = k
        np.maximum(conf, pk, out=conf)
    kmax = int(math.floor(float(f_high) + 0.5))
    order = np.array(order_traditional, dtype=np.int64) if kind == "physics" else cls
    if kind == "physics":
        order += cls
        order -= max_correction
        if wrap_orders:
            order = BW.modulo_orders(order, int(wrap_orders), kmax)
    np.clip(order, 0, kmax, out=order)
    order[~np.asarray(ok, dtype=bool)] = -1
    conf[~np.asarray(ok, dtype=bool)] = _F32(0.0)
    return order, conf
