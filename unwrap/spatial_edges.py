"""The graph cut's smoothness weights scaled by the probability that two neighbours lie on one surface,
given the temporal prior's step between them (issue 21, item 4: "cut where the phase says a depth edge is").

The smoothness term of :mod:`unwrap.spatial_orders` counts the 2 pi jumps of the corrected absolute
high-frequency phase between 4-neighbours. Its hard cuts (:func:`unwrap.spatial_orders.edge_weights`)
remove an edge where the wrapped high phase steps by more than pi/2 or the prior by more than 1.5
fringes. A depth edge whose projector jump is about one fringe passes both: the high phase looks
continuous (a whole period is invisible to it) and the prior steps by ~1, which the 1.5 threshold
must let through because the raw prior steps by 1 wherever the wrapped phase wraps on a smooth
surface. There the smoothness pulls right orders to their neighbours' (measured on the twin's MW / NT
beat-wrap pairs: docs/learned.md, "The graph cut's depth-edge weight").

The prior says which it is. With the prior ``r`` (real-valued order, fringes of the high frequency)
and the wrapped high phase ``phi``, the prior's estimate of the absolute phase is ``r + phi / 2 pi``,
so between neighbours p, q

    e = (r_p - r_q) + round((phi_p - phi_q) / 2 pi)       (fringes)

is the prior's estimate of the whole-fringe part of the step of the absolute phase: ~0 on a surface
(a fringe wrap included), ~k across a depth edge of k fringes. Its likelihood is the prior's own
model, the one of the data term (:func:`unwrap.spatial_orders.prior_data_cost`): a Gaussian of the
prior's noise, ``sigma_p^2 + sigma_q^2`` (fringes^2, independent pixels), mixed with a uniform part
of weight ``outlier`` per fringe (a biased coarse phase),

    L_k(e) = (1 - outlier) N(e; k, sigma_p^2 + sigma_q^2) + outlier.

Two hypotheses: one surface (k = 0) and a depth step of the nearest whole number of fringes
``k = sign(e) max(1, |round(e)|)``, with prior odds ``odds`` (step : surface) per edge. The posterior
probability of one surface is ``P = 1 / (1 + odds L_k(e) / L_0(e))`` and the edge's weight becomes
``weight * P``. A one-fringe step of a reliable prior (sigma 0.02 per pixel: L_1 / L_0 = 270) weakens
the edge to 1 / (1 + 270 odds) of its weight (a ninth at the shipped 0.03); the same step in a noisy
prior (sigma 0.3: 9; 0.79 of the weight) or a step that
fits neither hypothesis (e = 0.75 with a sharp prior: a bias band's boundary, L_1 / L_0 = 1) keeps
most of it; a small step (e near 0) keeps all of it. The outlier part caps the ratio at
``1 + (1 - outlier) / (outlier sqrt(2 pi (sigma_p^2 + sigma_q^2)))``: no step is ever sure enough
to cut an edge outright. ``odds`` is the one new constant (``unwrap.spatial_orders.DEFAULTS
["step_odds"]``, chosen on the twin validation scenes by ``python -m bench.spatial_edge_odds``;
never on real captures or the beat-wrap test pairs); ``outlier`` is the data term's.

SYNOPSIS

    >>> import numpy as np
    >>> same_surface_probability(np.array([0.02, 1.0, 1.0]), np.zeros(3), np.array([0.05, 0.05, 0.5]),
    ...                          np.array([0.05, 0.05, 0.5]), odds=0.1, outlier=0.05).round(3).tolist()
    [0.999, 0.085, 0.808]
"""
from __future__ import annotations

import math

import numpy as np

from ._xp import TWO_PI
from .errors import UnwrapError


def _check_odds(odds: float) -> float:
    odds = float(odds)
    if not (math.isfinite(odds) and odds >= 0):
        raise UnwrapError(f"step_odds must be finite and >= 0, got {odds!r}")
    return odds


def prior_likelihood(z, sigma, outlier: float):
    """The temporal prior's likelihood (per fringe) of a residual of ``z`` standard deviations
    ``sigma`` (fringes), any equal shapes: ``(1 - outlier) N(z sigma; 0, sigma) + outlier``, a
    Gaussian of the prior's noise mixed with a uniform part of weight ``outlier`` (a biased coarse
    phase). The model of the graph cut's data term (:func:`unwrap.spatial_orders.prior_data_cost`) and of the depth-edge weight
    (:mod:`unwrap.spatial_edges`)."""
    return (1.0 - outlier) * (np.exp(-0.5 * z * z) / (math.sqrt(2 * math.pi) * sigma)) + outlier


def same_surface_probability(prior_step, phase_step, sigma_p, sigma_q, *, odds: float, outlier: float) -> np.ndarray:
    """Posterior probability (same shape as the inputs, float64 in [0, 1]) that two neighbours lie on
    one surface (no whole-fringe jump of the absolute phase between them), from the step of the
    prior ``r_p - r_q`` (fringes), the raw step of the wrapped high phase ``phi_p - phi_q`` (rad,
    not wrapped) and the prior's noise at p and q (fringes, > 0). ``odds``: prior odds of a depth
    step against one surface, 0 gives 1 everywhere (the weights unchanged); ``outlier`` in [0, 1):
    the uniform part of the prior's likelihood (module docstring)."""
    odds = _check_odds(odds)
    if not 0 <= outlier < 1:
        raise UnwrapError(f"outlier must lie in [0, 1), got {outlier!r}")
    dr = np.asarray(prior_step, dtype=np.float64)
    if odds == 0:
        return np.ones(dr.shape)
    e = dr + np.rint(np.asarray(phase_step, dtype=np.float64) / TWO_PI)
    s = np.sqrt(np.maximum(np.asarray(sigma_p, dtype=np.float64) ** 2 + np.asarray(sigma_q, dtype=np.float64) ** 2,
                           1e-300))
    k = np.where(e >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(np.rint(e)))
    like_0 = prior_likelihood(e / s, s, outlier)
    like_k = prior_likelihood((e - k) / s, s, outlier)
    return like_0 / (like_0 + odds * like_k)


def scale_grid_weights(wx, wy, prior, phase_high, sigma, *, odds: float, outlier: float):
    """(wx, wy) of :func:`unwrap.spatial_orders.edge_weights` ((H, W-1), (H-1, W)) times the
    same-surface probability of each 4-neighbour pair (``prior`` fringes, ``phase_high`` wrapped
    rad, ``sigma`` fringes: (H, W) or scalar). Edges already cut stay 0."""
    r = np.nan_to_num(np.asarray(prior, dtype=np.float64))
    phi = np.nan_to_num(np.asarray(phase_high, dtype=np.float64))
    s = np.broadcast_to(np.nan_to_num(np.asarray(sigma, dtype=np.float64), nan=1.0), r.shape)
    if r.shape != phi.shape or np.shape(wx) != (r.shape[0], r.shape[1] - 1) or np.shape(wy) != (r.shape[0] - 1, r.shape[1]):
        raise UnwrapError(f"scale_grid_weights: prior {r.shape}, phase {phi.shape}, weights {np.shape(wx)}, "
                          f"{np.shape(wy)} do not match")
    px = same_surface_probability(r[:, :-1] - r[:, 1:], phi[:, :-1] - phi[:, 1:], s[:, :-1], s[:, 1:], odds=odds,
                                  outlier=outlier)
    py = same_surface_probability(r[:-1] - r[1:], phi[:-1] - phi[1:], s[:-1], s[1:], odds=odds, outlier=outlier)
    return np.asarray(wx, dtype=np.float64) * px, np.asarray(wy, dtype=np.float64) * py


def scale_pair_weights(p, q, w, prior, phase_high, sigma, *, odds: float, outlier: float):
    """(p, q, w * P) for extra pairs (flat row-major pixel indices, :func:`unwrap.spatial_orders.bridge_edges`)."""
    r = np.nan_to_num(np.asarray(prior, dtype=np.float64)).reshape(-1)
    phi = np.nan_to_num(np.asarray(phase_high, dtype=np.float64)).reshape(-1)
    s = np.broadcast_to(np.nan_to_num(np.asarray(sigma, dtype=np.float64), nan=1.0),
                        np.shape(prior)).reshape(-1)
    p, q = np.asarray(p, dtype=np.int64), np.asarray(q, dtype=np.int64)
    return p, q, np.asarray(w, dtype=np.float64) * same_surface_probability(r[p] - r[q], phi[p] - phi[q], s[p], s[q],
                                                                            odds=odds, outlier=outlier)


def scale_weights(wx, wy, extra, prior, phase_high, sigma, *, odds: float, outlier: float):
    """(wx, wy, extra) scaled by :func:`scale_grid_weights` / :func:`scale_pair_weights` (``extra``
    None stays None); ``odds`` 0 returns them unchanged."""
    if not _check_odds(odds):
        return wx, wy, extra
    wx, wy = scale_grid_weights(wx, wy, prior, phase_high, sigma, odds=odds, outlier=outlier)
    if extra is not None:
        extra = scale_pair_weights(*extra, prior, phase_high, sigma, odds=odds, outlier=outlier)
    return wx, wy, extra


__all__ = ["prior_likelihood", "same_surface_probability", "scale_grid_weights", "scale_pair_weights", "scale_weights"]
