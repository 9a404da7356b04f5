"""Classical baselines beside the network: traditional TPU with the coarse phase spatially filtered.

(The plain traditional TPU is the dataset's ``order_traditional``; the prior-free network, the
paper's DT-TPU, is the ``prior_free`` model kind of the same code.)

The coarse absolute phase of each method is filtered over the valid pixels of a
``window x window`` box (a local least-squares plane by default, or the mean:
:mod:`unwrap.learned.smoothing`), and the method's rounding is redone with it:

- MF: the unit-frequency phase ``Phi_lo`` (absolute), ``prior = (f_hi/f_lo Phi_lo - phi_hi) / 2 pi``;
- MW: the beat phase ``wrap(phi_hi - phi_lo)`` of ``f_hi - f_lo <= 1`` periods (absolute),
  ``prior = (f_hi/(f_hi - f_lo) Phi_beat - phi_hi) / 2 pi`` (the 2-wavelength step of mw_unwrap);
- NT: a coprime pair one period apart (47, 48; 95, 96) has the same absolute beat; the filtered
  order is decoded from it as for MW. NT's own residue mixes both fine phases and has no coarse
  phase to filter; pairs further apart are refused.

Averaging removes independent pixel noise (by ~1/window) but not a bias shared by the window:
global illumination and defocus bias the low-frequency phase coherently over whole surfaces, and
there the filtered baseline fails as the unfiltered one does - the reason to learn. Near depth
steps the box mixes two surfaces and adds errors of its own.

SYNOPSIS

    >>> import numpy as np
    >>> from unwrap.learned.baselines import filtered_order
    >>> u = np.tile(np.arange(200.0), (20, 1)) + 300           # projector columns seen by 20x200 pixels
    >>> Phi = lambda f: 2 * np.pi * f * u / 912
    >>> wrap = lambda x: np.angle(np.exp(1j * x))
    >>> rng = np.random.default_rng(0)
    >>> lo = wrap(Phi(1) + rng.normal(0, 0.05, u.shape)); hi = wrap(Phi(48))
    >>> k_true = np.round((Phi(48) - hi) / (2 * np.pi))
    >>> k = filtered_order("mf", lo, hi, (1, 48), np.ones(u.shape, bool), window=15)
    >>> float((k != k_true).mean()) < 0.01
    True
"""
from __future__ import annotations

import math

import numpy as np
from .._xp import TIE_BAND, round_order
from ..methods import PAIR_METHODS, check_method
from . import beat_window as BW
from .errors import ModelError


def filtered_order(method: str, phase_low, phase_high, frequencies, valid, *, window: int = 15,
                   fit: str = "plane", width=None) -> np.ndarray:
    """Fringe order (int64, -1 invalid) of the high frequency with the coarse phase filtered.

    ARGUMENTS: method; wrapped phases (rad, (H, W)); frequencies (low, high); valid (H, W) bool;
    window (px, odd); fit "plane" (local least-squares plane, default) or "mean" (box mean); width =
    projector pixels across the fringes (places the 2 pi cut of the coarse phase as
    unwrap.temporal does; optional).

    With numba and ``fit="plane"``, MF: the plane kernel between two compiled per-pixel passes
    (:mod:`unwrap.learned._filtered_kernel`), the same orders as the numpy formulation
    (:func:`_filtered_order_numpy`, used otherwise). MW / NT take the numpy formulation, whose beat
    is filtered as a periodic phase (:mod:`unwrap.learned.beat_window`: a pair declared on its
    common window has the beat's wrap inside the image).
    """
    check_method(method, PAIR_METHODS, ModelError)
    f_lo, f_hi = (float(f) for f in frequencies)
    if method != "mf" and f_hi - f_lo > 1 + 1e-9:
        raise ModelError(f"{method} pair ({f_lo:g}, {f_hi:g}): the filtered baseline needs a beat of at most "
                         f"1 period (an absolute coarse phase); this pair's is {f_hi - f_lo:g}")
    valid = np.asarray(valid, dtype=bool)
    if fit == "plane" and method == "mf":       # MW / NT: the beat filtered as a periodic phase (numpy path)
        try:
            from . import _filtered_kernel as FK
            from ._plane_kernel import plane_filter_kernel
        except ImportError:
            pass
        else:
            return _filtered_order_compiled(FK, plane_filter_kernel, method, phase_low, phase_high, f_lo, f_hi,
                                            valid, window, width)
    return _filtered_order_numpy(method, phase_low, phase_high, f_lo, f_hi, valid, window, fit, width)


def _filtered_order_compiled(FK, plane_kernel, method, phase_low, phase_high, f_lo, f_hi, valid, window, width):
    """:func:`filtered_order` as coarse pass -> plane kernel -> order pass (numba)."""
    from .fast_features import coarse_cut

    f_c, cut = coarse_cut(method, f_lo, f_hi, width)
    lo, hi = (a if isinstance(a, np.ndarray) and a.dtype in (np.float32, np.float64) else np.asarray(a, np.float64)
              for a in (phase_low, phase_high))
    ok = np.ascontiguousarray(valid)
    Phi = np.empty(ok.shape)
    if FK.coarse_kernel(lo, hi, ok, method == "mf", cut, Phi):
        FK.coarse_fix(lo, hi, ok, method == "mf", cut, Phi)
    Ps = plane_kernel(Phi, ok, (int(window) | 1) // 2)
    k = np.empty(ok.shape, dtype=np.int64)
    FK.order_kernel(Ps, hi, ok, f_hi / f_c, 2 * math.pi, 0.5 + TIE_BAND, float(math.floor(f_hi + 0.5)), k)
    return k


def _filtered_order_numpy(method, phase_low, phase_high, f_lo, f_hi, valid, window, fit, width):
    """The numpy formulation of :func:`filtered_order` (the reference of the compiled path)."""
    from .fast_features import smoothed_priors

    t = lambda a: np.where(valid, np.nan_to_num(np.asarray(a, dtype=np.float64)), 0.0)  # noqa: E731
    priors, _ = smoothed_priors(method, t(phase_low), t(phase_high), f_lo, f_hi, valid, (window,), fit, width)
    prior = priors[int(window) | 1]
    ok = valid & np.isfinite(prior)
    period = BW.wrap_orders(method, f_lo, f_hi)
    k = round_order(np.where(ok, prior, 0.0))
    k = BW.modulo_orders(k, period, math.floor(f_hi + 0.5)) if period else np.clip(k, 0, math.floor(f_hi + 0.5))
    return np.where(ok, k, -1).astype(np.int64)
