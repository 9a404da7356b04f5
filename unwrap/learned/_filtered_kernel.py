"""numba kernels of :func:`unwrap.learned.baselines.filtered_order` around the plane filter
(imported only when numba is installed).

The numpy formulation makes ~10 whole-image float64 passes besides the plane fit (NaN cleaning,
the coarse phase and its 2 pi cut, the prior, the rounding and its clip); here they are two
per-pixel passes, parallel over rows (``prange``), each reading its inputs once:

1. :func:`coarse_kernel` (before the plane filter, which needs the whole coarse image): the
   cleaned phases (``nan_to_num``, 0 outside ``valid``), the MF unit phase or the MW / NT beat
   ``wrap(phi_hi - phi_lo)``, cut at ``cut`` as ``np.remainder(coarse - cut, 2 pi) + cut``;
2. :func:`order_kernel` (after it): the prior ``(g Phi_s - phi_hi) / 2 pi``, ``valid`` and finite,
   rounded as :func:`unwrap._xp.round_order` (ties down) and clipped to ``[0, k_max]``; -1 elsewhere.

float64 throughout, operation for operation as the numpy code (same expressions in the same
order, ``fmod``-based remainder with numpy's sign rule, no fastmath so no contraction into FMA):
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


@nb.njit(inline="always")
def _remainder(a, b):
    """``np.remainder(a, b)`` for float64 (fmod, then numpy's sign rule)."""
    m = np.fmod(a, b)
    if m != 0.0:
        if (b < 0.0) != (m < 0.0):
            m += b
    else:
        m = math.copysign(0.0, b)
    return m


@nb.njit(parallel=True, **_JIT)
def coarse_kernel(phase_low, phase_high, valid, is_mf, cut, out):
    """``out`` (H, W) float64 <- the cut absolute coarse phase (rad) of the cleaned phases."""
    H, W = out.shape
    for y in nb.prange(H):
        for x in range(W):
            ok = valid[y, x]
            lo = _clean(phase_low[y, x], ok)
            if is_mf:
                c = lo
            else:
                d = _clean(phase_high[y, x], ok) - lo
                c = d + _TWO_PI * np.floor((math.pi - d) / _TWO_PI)          # unwrap._xp.wrap
            out[y, x] = _remainder(c - cut, _TWO_PI) + cut


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
