"""The learned path on an MW / NT pair whose beat repeats inside the image (issue 21, item 5).

An MW or NT pair of pitches ``p1 < p2`` projector px is unique only over its beat period
``L = p1 p2 / (p2 - p1)`` px (45/48 px: 720; 42/48: 336; 42/45: 630), shorter than most
projectors (912 px and more). Such a pair is declared **on its common window**: the capture's
``[projector] size`` across the fringes is ``L`` and its frequencies are ``L / p2``, ``L / p1``
(e.g. 15 and 16 periods over 720 px), so the beat is one period across the declared pattern. The
decode is then exact modulo the window: a pixel lit by column ``u`` gets ``u mod L`` (the
traditional decode: :func:`unwrap.temporal.mw_unwrap` / ``nt_unwrap``, whose range constraint moves
a phase by the ``f_hi`` orders of one window), and the beat's phase jumps by 2 pi in the image
wherever the lit field crosses a multiple of ``L``.

What the network's inputs assumed before: that the coarse (beat) phase is continuous over the
image, cut only at the pattern's edge. Its local plane fits (the smoothed-prior channels of
:mod:`unwrap.learned.fast_features`, 7 and 15 px boxes) then averaged across the jump and missed
by up to half a window (8 of 16 orders), the disagreement channel said "filtering changes the
decision" there, and the correction was clipped to [0, f_hi] instead of taken modulo the window:
the network broke right orders along every wrap line (``python -m bench.beat_wrap``). Here:

- :func:`circular_plane_filter`: the plane fit of a phase that is periodic (2 pi), on the branch
  of each pixel: two fits, one with the cut where the decode puts it and one with the cut half a
  period away; a pixel uses the fit whose cut is farther from its own phase, moved by whole
  periods to the pixel's branch. Where no box reaches a cut it equals the plain fit (to rounding).
- :func:`nearest_branch`: a smoothed prior moved by whole windows to the traditional order's
  branch (the disagreement channel then measures what filtering changes, not which window).
- :func:`wrap_orders`: the orders one coarse period moves (``f_hi / f_beat``; None when not whole),
  and :func:`modulo_orders`: a corrected order taken into [0, f_hi] modulo that period.

MF is left as it was: the unit phase spans the pattern by definition.

SYNOPSIS

    >>> import numpy as np
    >>> from unwrap.learned.beat_window import circular_plane_filter
    >>> from unwrap.learned.fast_features import plane_filter
    >>> x = np.tile(np.arange(40.0), (9, 1))
    >>> Phi = np.remainder(0.3 * x, 2 * np.pi)              # a ramp that wraps twice
    >>> out = circular_plane_filter(Phi, np.ones(Phi.shape, bool), 0.0, (7,), plane_filter)[7]
    >>> bool(np.allclose(out, Phi))                        # the plain plane fit misses at each wrap
    True
"""
from __future__ import annotations

import math

import numpy as np

from ..common_window import pair_wrap_orders as wrap_orders  # noqa: F401  (public here)

TWO_PI = 2.0 * math.pi


def circular_plane_filter(Phi, valid, cut: float, windows, plane_filter, fit: str = "plane") -> dict:
    """{window: plane-filtered ``Phi`` (H, W) float64} of a phase known modulo 2 pi.

    ``Phi``: the coarse phase (rad) in [cut, cut + 2 pi); ``valid`` (H, W) bool; ``windows``: box
    sizes (px); ``plane_filter``, ``fit``: the filter
    (:func:`unwrap.learned.fast_features.plane_filter`) and its kind. A pixel whose phase lies in the middle
    half of the range keeps the plain fit (its box does not reach the cut unless it spans a
    quarter period); the others take the fit of the phase cut half a period away, moved by whole
    periods to their own branch. Invalid pixels keep ``Phi``."""
    Phi = np.asarray(Phi, dtype=np.float64)
    plain = plane_filter(Phi, valid, windows, fit)
    rel = Phi - cut
    mid = (rel >= 0.5 * math.pi) & (rel < 1.5 * math.pi)
    mid |= ~np.asarray(valid, dtype=bool)          # invalid pixels keep Phi (the plain fit's), bit for bit
    if mid.all():
        return plain
    shifted = np.remainder(Phi - cut - math.pi, TWO_PI) + cut + math.pi     # the cut half a period on
    other = plane_filter(shifted, valid, windows, fit)
    out = {}
    for w, P in plain.items():
        Q = other[w]
        out[w] = np.where(mid, P, Q + TWO_PI * np.round((Phi - Q) / TWO_PI))
    return out


def nearest_branch(prior_smoothed, order, period: int):
    """``prior_smoothed`` moved by whole ``period`` orders to the branch nearest ``order`` (same
    shape and dtype); the fractional part is unchanged (``period`` whole)."""
    p = np.asarray(prior_smoothed)
    n = np.round((np.asarray(order, dtype=np.float64) - p) / period)
    return (p + period * n).astype(p.dtype, copy=False)


def modulo_orders(order, period: int, kmax: int):
    """Orders (int array) taken into [0, kmax] by whole ``period`` s: below 0 +period, above kmax
    -period (a correction across the window's wrap); still outside: clipped."""
    k = np.asarray(order, dtype=np.int64)
    k = np.where(k < 0, k + period, np.where(k > kmax, k - period, k))
    return np.minimum(np.maximum(k, 0), kmax)
