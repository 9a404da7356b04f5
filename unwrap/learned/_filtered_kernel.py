"""numba kernels of :func:`unwrap.learned.baselines.filtered_order` around the plane filter
(imported only when numba is installed).

The numpy formulation makes ~10 whole-image float64 passes besides the plane fit (NaN cleaning,
the coarse phase and its 2 pi cut, the prior, the rounding and its clip); here they are two
per-pixel passes, parallel over rows (``prange``), each reading its inputs once:

1. :func:`coarse_kernel` (before the plane filter, which needs the whole coarse image): the
   cleaned phases (``nan_to_num``, 0 outside ``valid``), the MF unit phase or the MW / NT beat
   ``wrap(phi_hi - phi_lo)``, cut at ``cut`` as ``np.remainder(coarse - cut, 2 pi) + cut``
   (pixels whose inputs are not wrapped phases are redone with numpy: :func:`coarse_fix`);
2. :func:`order_kernel` (after it): the prior ``(g Phi_s - phi_hi) / 2 pi``, ``valid`` and finite,
   rounded as :func:`unwrap._xp.round_order` (ties down) and clipped to ``[0, k_max]``; -1 elsewhere.

float64 throughout, operation for operation as the numpy code (same expressions in the same
order, numpy's remainder, no fastmath so no contraction into FMA):
the orders are bit-identical to it, which the tests check. float32 would not do: the prior of a
48-period fringe spans ~48 orders and is rounded at +-0.5, so float32's ~6e-8 relative error
(~3e-6 orders) would move orders near a rounding boundary that the float64 reference keeps, and
the coarse phase feeds the plane fit, whose moments need float64 (:mod:`unwrap.learned._plane_kernel`).
Compiled code is cached on disk (the first call in a fresh environment compiles: seconds).
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

_JIT = dict(cache=True, error_model="numpy", nogil=True)
_BIG = np.finfo(np.float64).max
_TWO_PI = 2.0 * math.pi


@nb.njit(inline="always")
def _clean(a, ok):
    """``np.where(ok, np.nan_to_num(a), 0.0)`` of one value, as float64."""
    if not ok:
        return 0.0
    v = np.float64(a)
    if v != v:
        return 0.0
    if v == np.inf:
        return _BIG
    if v == -np.inf:
        return -_BIG
    return v


@nb.njit(parallel=True, **_JIT)
def coarse_kernel(phase_low, phase_high, valid, is_mf, cut, out):
    """``out`` (H, W) float64 <- the cut absolute coarse phase (rad) of the cleaned phases, where
    ``coarse - cut`` lies in (-2 pi, 2 pi): there ``np.remainder`` is ``a`` itself or ``a + 2 pi``
    (fmod is exact and returns ``a`` when ``|a| < 2 pi``; numpy's sign rule then adds 2 pi to a
    negative one). Elsewhere (non-wrapped or infinite inputs) NaN; returns how many such pixels,
    which :func:`coarse_fix` redoes with numpy. (A libm fmod in the loop, even in a branch never
    taken, costs ~4 ms a 640 x 480 image: the compiler evaluates it unconditionally.)"""
    H, W = out.shape
    n = 0
    for y in nb.prange(H):
        for x in range(W):
            ok = valid[y, x]
            lo = _clean(phase_low[y, x], ok)
            if is_mf:
                c = lo
            else:
                d = _clean(phase_high[y, x], ok) - lo
                c = d + _TWO_PI * np.floor((math.pi - d) / _TWO_PI)          # unwrap._xp.wrap
            a = c - cut
            if 0.0 < a < _TWO_PI:
                out[y, x] = a + cut
            elif -_TWO_PI < a < 0.0:
                out[y, x] = (a + _TWO_PI) + cut
            elif a == 0.0:
                out[y, x] = 0.0 + cut                                         # remainder(+-0, b) = +0
            else:
                out[y, x] = np.nan
                n += 1
    return n


def coarse_fix(phase_low, phase_high, valid, is_mf, cut, out):
    """Redo with numpy (``np.remainder``) the pixels :func:`coarse_kernel` left NaN."""
    from .._xp import wrap

    idx = np.nonzero(np.isnan(out))
    t = lambda a: np.where(valid[idx], np.nan_to_num(np.asarray(a, np.float64)[idx]), 0.0)  # noqa: E731
    with np.errstate(over="ignore", invalid="ignore"):                 # +-1.8e308 from infinite phases
        lo = t(phase_low)
        c = lo if is_mf else wrap(t(phase_high) - lo)
        out[idx] = np.remainder(c - cut, 2 * math.pi) + cut


@nb.njit(parallel=True, **_JIT)
def order_kernel(Phi_s, phase_high, valid, g, two_pi, half, k_max, out):
    """``out`` (H, W) int64 <- the clipped order of ``(g Phi_s - phi_hi) / two_pi``, -1 where not
    ``valid`` or not finite. ``half`` = 0.5 + TIE_BAND; ``k_max`` float."""
    H, W = out.shape
    for y in nb.prange(H):
        for x in range(W):
            ok = valid[y, x]
            p = (g * Phi_s[y, x] - _clean(phase_high[y, x], ok)) / two_pi
            if ok and math.isfinite(p):
                k = np.ceil(p - half)                # float, as round_order (math.ceil: int64)
                out[y, x] = np.int64(min(max(k, 0.0), k_max))
            else:
                out[y, x] = -1
