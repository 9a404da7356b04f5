"""Spatial fringe-order correction by energy minimisation, solved exactly with one graph cut.

Per valid pixel p the unknown is an integer correction ``c_p`` in ``{-K, ..., K}`` added to the
traditional order ``n_p`` (what rounding the temporal prior gives). The energy is

    E(c) = sum_p D_p(c_p) + sum_{p~q} w_pq |m_pq + c_p - c_q|

- ``D_p``: a data term in nats, the negative log-likelihood of each correction. The classical
  baseline (:func:`prior_data_cost`) takes it from the temporal prior ``r_p`` (the real-valued
  order before rounding): a Gaussian of the prior's noise ``sigma_r`` (from the reliability model:
  the phase noise of each pattern, :func:`prior_sigma`) mixed with a uniform outlier part of
  weight ``outlier`` - a biased coarse phase (interreflection, defocus at occlusion edges) makes
  the prior wrong by up to fringes over whole patches, and there the data term must become flat
  and let the neighbours decide. The learned path uses the network's class log-probabilities.
- the smoothness term counts the 2 pi jumps of the corrected absolute high-frequency phase
  ``Phi = phi + 2 pi (n + c)`` between 4-neighbours: ``m_pq + c_p - c_q =
  round((Phi_p - Phi_q) / 2 pi)``, zero where ``|Phi_p - Phi_q| < pi``. ``w_pq`` (nats per jump)
  is cut to zero where the phase says a depth edge is (:func:`edge_weights`: a large wrapped
  phase step, a prior step of more than ``max_prior_step`` fringes, low modulation, an invalid
  neighbour), so an occlusion edge never pulls orders across; with the prior's data term the
  remaining weights are scaled by the probability that the neighbours lie on one surface given the
  prior's step (:mod:`unwrap.spatial_edges`: a one-fringe depth step the high phase cannot see).

The pairwise term is a convex function of the label difference, so the energy is minimised
*exactly* (not by alpha-expansion's local moves) by Ishikawa's layered graph (H. Ishikawa, "Exact
optimization for Markov random fields with convex priors", IEEE TPAMI 25(10), 2003): ``2K``
binary nodes per pixel, ``u_i = [c + K > i]``, a single s-t min cut with PyMaxflow (Boykov-Kolmogorov).
Everything is built with vectorised numpy edge lists; only valid pixels get nodes.

SYNOPSIS

    >>> import numpy as np
    >>> from unwrap.spatial_orders import solve_corrections, edge_weights
    >>> phi = np.zeros((4, 6)); order = np.zeros((4, 6), np.int64); order[:, 3:] = 1   # a 1-fringe patch
    >>> cost = np.zeros((5, 4, 6)); valid = np.ones((4, 6), bool)
    >>> wx, wy = edge_weights(phi, valid, weight=1.0)
    >>> cost[:, :, :3] = np.array([5, 5, 0, 5, 5.])[:, None, None]      # left half: sure of c = 0
    >>> c, _ = solve_corrections(cost, phi, order, valid, wx, wy)
    >>> c[:, 3:].tolist() == [[-1] * 3] * 4                          # the patch joins its surroundings
    True
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ._xp import TWO_PI, wrap
from .errors import UnwrapError
from .spatial_edges import prior_likelihood, scale_weights

#: Default label range: corrections -2 ... +2 (the learned network's classes).
MAX_CORRECTION = 2
#: Cost of an order outside [0, round(f)] (nats): never chosen while any other label exists.
OUT_OF_RANGE_COST = 1e4
_INF = 1e12

#: Energy parameters (nats per 2 pi jump; the prior likelihood's outlier weight; a noise floor of
#: the prior in fringes - 1/100 fringe, so that noise-free frames, whose fit residual is ~1e-14,
#: still give a finite likelihood), set on the twin validation scenes by ``python -m bench.spatial_unwrap
#: --calibrate`` (never on real captures). ``bias_scale`` (the bias spread per fringe of the
#: global-light bound) and ``bias_max_correction`` (the label range with the bound: a bias of
#: several fringes needs corrections beyond +-2) were chosen together on the 12 validation scenes
#: (``python -m bench.global_bias --calibrate``; docs/learned.md, "A global-light bound").
#: Smoothness / outlier recalibrated in session 11 (were 4 / 0.2, stale since the noise estimate
#: of 441dd4d; docs/learned.md, "The graph cut's weights recalibrated").
#: ``step_odds``: prior odds of a whole-fringe depth step on an edge, which scale the smoothness by
#: the probability that the neighbours lie on one surface given the prior's step (the prior's data
#: term only; :mod:`unwrap.spatial_edges`; session 12, docs/learned.md "The graph cut's depth-edge weight").
DEFAULTS = {"smoothness": 8.0, "outlier": 0.05, "sigma_floor": 0.01, "smoothness_learned": 32.0, "bias_scale": 0.5,
            "bias_max_correction": 4, "step_odds": 0.03}
#: Never-worse gate thresholds per path (:func:`gate`), calibrated the same way: a correction is
#: applied where the traditional decision's error probability - bias included, the model of
#: :mod:`unwrap.decision_error` - is at least ``min_p_wrong`` and the network's probability of the
#: new label at least ``min_confidence``; chosen as the least error on the validation scenes
#: (``bench.spatial_unwrap --calibrate-gate``: the scenes of spatial_val.toml; the error model is
#: fitted on those and the interreflection scenes of decision_error_val.toml, on which no gate of
#: this form meets the rule: docs/learned.md) with every scene's broken orders (right -> wrong) at
#: most 5 % of its fixed ones (``bench.spatial_unwrap.BREAK_RATIO``). Recalibrated for the shipped
#: width-8 network on a finer confidence grid (learned: 0.85, whose worst validation scene breaks
#: 4.8 % of its fixes against the 5 % allowed: a thin margin; docs/learned.md, "The never-worse
#: gate recalibrated for the width-8 model").
GATE = {"Graph cut": {"min_p_wrong": 3e-3, "min_confidence": 0.0},
        "Learned": {"min_p_wrong": 3e-3, "min_confidence": 0.85},
        "Learned + graph cut": {"min_p_wrong": 3e-3, "min_confidence": 0.5}}


def _check_maps(name_shape: dict) -> tuple:
    shapes = {k: np.shape(v) for k, v in name_shape.items()}
    first = next(iter(shapes.values()))
    if len(first) != 2 or any(s != first for s in shapes.values()):
        raise UnwrapError("spatial orders: expected one (H, W) shape for " +
                          ", ".join(f"{k} {s}" for k, s in shapes.items()))
    return first


def prior_sigma(method: str, frequencies, sigma_phase_low, sigma_phase_high):
    """Standard deviation (fringes of the high frequency) of the temporal prior from the phase
    noise (rad, scalars or (H, W)) of the two patterns.

    MF (unit or low frequency f_lo): ``r = (R Phi_lo - phi_hi) / 2 pi``, ``R = f_hi / f_lo``;
    MW / NT with a beat of at most one period: ``r = ((f_hi/b) (phi_hi - phi_lo) - phi_hi) / 2 pi``,
    ``b = f_hi - f_lo``. Independent noise in both patterns.
    """
    f_lo, f_hi = (float(f) for f in frequencies)
    s_lo, s_hi = (np.asarray(s, dtype=np.float64) for s in (sigma_phase_low, sigma_phase_high))
    if method == "mf":
        a, b = f_hi / f_lo, 1.0
    elif method in ("mw", "nt"):
        beat = f_hi - f_lo
        if not 0 < beat <= 1 + 1e-9:
            raise UnwrapError(f"{method} pair ({f_lo:g}, {f_hi:g}): the spatial stage needs a beat of at most "
                              f"one period (an absolute coarse phase), this one is {beat:g}")
        a, b = f_hi / beat, f_hi / beat - 1.0
    else:
        raise UnwrapError(f"method {method!r}: expected 'mf', 'mw' or 'nt'")
    return np.sqrt((a * s_lo) ** 2 + (b * s_hi) ** 2) / TWO_PI


def phase_noise(modulation, steps: int, noise_sigma: float):
    """Per-pixel phase noise (rad) of N-step least squares, ``sqrt(2 / N) sigma / B``
    (:func:`unwrap.reliability.phase_sigma`, vectorised; B and sigma in the same units). Pixels
    with B <= 0 get pi (no information)."""
    if steps < 3 or not (math.isfinite(noise_sigma) and noise_sigma > 0):
        raise UnwrapError(f"phase_noise needs steps >= 3 and a finite noise sigma > 0; got {steps}, {noise_sigma}")
    B = np.nan_to_num(np.asarray(modulation, dtype=np.float64))
    return np.where(B > 0, math.sqrt(2.0 / steps) * noise_sigma / np.where(B > 0, B, 1.0), math.pi).clip(max=math.pi)


def _labels(max_correction: int) -> np.ndarray:
    if int(max_correction) != max_correction or not 1 <= max_correction <= 8:
        raise UnwrapError(f"max_correction must be an integer in 1..8, got {max_correction!r}")
    return np.arange(-int(max_correction), int(max_correction) + 1)


def prior_data_cost(prior, order, sigma, valid, *, frequency_high: float, max_correction: int = MAX_CORRECTION,
                    outlier: float = 0.05, bias_sigma=None) -> np.ndarray:
    """Data term (L, H, W) float64, nats: ``-log((1 - outlier) N(r; n + c, sigma) + outlier)`` per
    correction c (L = 2 K + 1, label index c + K), with the prior r, the traditional order n and
    sigma (fringes, (H, W) or scalar). An order outside [0, round(f_high)] costs
    :data:`OUT_OF_RANGE_COST`; invalid pixels cost 0. ``outlier`` in [0, 1): the weight of the
    uniform part (per fringe); 0 gives the plain Gaussian. ``bias_sigma`` (fringes, (H, W) or
    scalar, >= 0; None: none): the spread of the coarse phase's bias, added in quadrature to
    ``sigma`` (:func:`graphcut_orders`' ``bias_bound``: a scale of :mod:`unwrap.global_light`'s bound)."""
    _check_maps({"prior": prior, "order": order, "valid": valid})
    if not 0 <= outlier < 1:
        raise UnwrapError(f"outlier must lie in [0, 1), got {outlier!r}")
    c = _labels(max_correction)[:, None, None].astype(np.float64)
    valid = np.asarray(valid, dtype=bool)
    r = np.asarray(prior, dtype=np.float64)
    s = np.broadcast_to(np.asarray(sigma, dtype=np.float64), r.shape)
    if bias_sigma is not None:
        b = np.broadcast_to(np.nan_to_num(np.asarray(bias_sigma, dtype=np.float64), nan=np.inf), r.shape)
        if np.any(valid & (b < 0)):
            raise UnwrapError("prior_data_cost: bias_sigma must be >= 0 at every valid pixel")
        s = np.sqrt(s * s + np.minimum(b, 1e6) ** 2)
    if np.any(valid & ~(np.isfinite(r) & np.isfinite(s))):
        raise UnwrapError("prior_data_cost: the prior or its sigma is not finite at pixels marked valid")
    if np.any(valid & ~(s > 0)):
        raise UnwrapError("prior_data_cost: sigma must be > 0 at every valid pixel")
    n = np.asarray(order, dtype=np.float64)
    r0, s0 = np.where(valid, r, 0.0), np.where(valid, s, 1.0)
    z = (r0 - np.where(valid, n, 0.0) - c) / s0
    cost = -np.log(prior_likelihood(z, s0, outlier) + 1e-300)
    cost -= cost.min(axis=0, keepdims=True)
    k = n + c
    cost = np.where((k < 0) | (k > math.floor(frequency_high + 0.5)), OUT_OF_RANGE_COST, cost)
    return np.where(valid, cost, 0.0)


def traditional_error_probability(prior, order, sigma, valid, *, max_correction: int = MAX_CORRECTION) -> np.ndarray:
    """(H, W) float64: the reliability model's probability that the traditional order is wrong,
    given the observed prior: ``1 - P(c = 0 | r)`` under the Gaussian noise model (no outlier
    part: this is what the noise model predicts, bias not included); 0 at invalid pixels."""
    cost = prior_data_cost(prior, order, sigma, valid, frequency_high=1e9, max_correction=max_correction, outlier=0.0)
    p = np.exp(-cost)
    p0 = p[int(max_correction)] / p.sum(axis=0)
    return np.where(np.asarray(valid, dtype=bool), 1.0 - p0, 0.0)


def edge_weights(phase_high, valid, *, weight: float, prior=None, modulation=None, min_modulation: float = 0.0,
                 max_wrapped_step: float = math.pi / 2, max_prior_step: float = 1.5):
    """Smoothness weights (nats per 2 pi jump) between 4-neighbours: ``(wx (H, W-1), wy (H-1, W))``.

    ``weight`` where both pixels are valid and the phase shows no depth edge between them; 0 (the
    term is cut) where either is invalid, the wrapped high phase steps by more than
    ``max_wrapped_step`` rad (after wrapping: a fringe edge is not a step), the prior steps by more
    than ``max_prior_step`` fringes (a projector jump the coarse phase sees), or either modulation
    (same units as ``min_modulation``) is at or below ``min_modulation``.
    """
    maps = {"phase_high": phase_high, "valid": valid}
    if prior is not None:
        maps["prior"] = prior
    if modulation is not None:
        maps["modulation"] = modulation
    _check_maps(maps)
    if not (math.isfinite(weight) and weight >= 0):
        raise UnwrapError(f"smoothness weight must be finite and >= 0, got {weight!r}")
    v = np.asarray(valid, dtype=bool)
    phi = np.nan_to_num(np.asarray(phase_high, dtype=np.float64))
    if modulation is not None:
        v = v & (np.nan_to_num(np.asarray(modulation, dtype=np.float64)) > min_modulation)

    def one(axis):
        d = np.abs(wrap(np.diff(phi, axis=axis)))
        ok = (np.take(v, range(v.shape[axis] - 1), axis=axis) & np.take(v, range(1, v.shape[axis]), axis=axis)
              & (d <= max_wrapped_step))
        if prior is not None:
            r = np.nan_to_num(np.asarray(prior, dtype=np.float64))
            ok &= np.abs(np.diff(r, axis=axis)) <= max_prior_step
        return np.where(ok, float(weight), 0.0)

    return one(1), one(0)


def _add_unary(acc, layer, nodes, amount):
    """Accumulate ``amount * u`` (amount >= 0: paid when u = 1) or the opposite sign."""
    np.add.at(acc, (layer, nodes), amount)


def bridge_edges(phase_high, valid, *, weight: float, prior=None, max_wrapped_step: float = math.pi / 2,
                 max_prior_step: float = 1.5, min_degree: int = 2):
    """Extra smoothness edges for pixels with fewer than ``min_degree`` valid 4-neighbours (speckled
    masks of noisy captures, where a 4-neighbour graph leaves them without context): to the valid
    pixels of their 5x5 box other than the 4-neighbours (diagonals and 2-px steps), weight
    ``weight / distance``, cut by the same criteria as :func:`edge_weights`.

    RETURNED VALUE: (p, q, w): flat pixel indices (row-major, int64) and weights."""
    v = np.asarray(valid, dtype=bool)
    H, W = v.shape
    phi = np.nan_to_num(np.asarray(phase_high, dtype=np.float64))
    r = None if prior is None else np.nan_to_num(np.asarray(prior, dtype=np.float64))
    deg = np.zeros((H, W), np.int64)
    deg[:, 1:] += v[:, :-1]
    deg[:, :-1] += v[:, 1:]
    deg[1:] += v[:-1]
    deg[:-1] += v[1:]
    low = v & (deg < min_degree)
    P, Q, Wt = [], [], []
    flat = np.arange(H * W).reshape(H, W)
    for dy in range(0, 3):
        for dx in range(-2, 3):
            if (dy, dx) <= (0, 0) or abs(dy) + abs(dx) <= 1:
                continue                                   # each pair once; 4-neighbours are edge_weights'
            ys, yd = slice(0, H - dy), slice(dy, H)
            xs, xd = (slice(0, W - dx), slice(dx, W)) if dx >= 0 else (slice(-dx, W), slice(0, W + dx))
            ok = v[ys, xs] & v[yd, xd] & (low[ys, xs] | low[yd, xd])
            ok &= np.abs(wrap(phi[ys, xs] - phi[yd, xd])) <= max_wrapped_step
            if r is not None:
                ok &= np.abs(r[ys, xs] - r[yd, xd]) <= max_prior_step
            P.append(flat[ys, xs][ok]), Q.append(flat[yd, xd][ok])
            Wt.append(np.full(int(ok.sum()), weight / math.hypot(dy, dx)))
    return np.concatenate(P), np.concatenate(Q), np.concatenate(Wt)


def _check_solver_inputs(cost, phase_high, order, valid, wx, wy):
    """Validated (cost, phi, valid, wx, wy) of :func:`solve_corrections` (UnwrapError naming the problem)."""
    H, W = _check_maps({"phase_high": phase_high, "order": order, "valid": valid})
    cost = np.asarray(cost, dtype=np.float64)
    if cost.ndim != 3 or cost.shape[1:] != (H, W) or cost.shape[0] % 2 != 1 or cost.shape[0] < 3:
        raise UnwrapError(f"cost {cost.shape}: expected (L, {H}, {W}) with L = 2 K + 1 >= 3 labels")
    wx, wy = np.asarray(wx, dtype=np.float64), np.asarray(wy, dtype=np.float64)
    if wx.shape != (H, W - 1) or wy.shape != (H - 1, W):
        raise UnwrapError(f"weights {wx.shape}, {wy.shape}: expected ({H}, {W - 1}) and ({H - 1}, {W})")
    valid = np.asarray(valid, dtype=bool)
    if not (np.all(np.isfinite(wx)) and np.all(np.isfinite(wy))) or (wx < 0).any() or (wy < 0).any():
        raise UnwrapError("smoothness weights must be finite and >= 0")
    if np.any(~np.isfinite(cost[:, valid])):
        raise UnwrapError("the data cost is not finite at pixels marked valid")
    phi = np.asarray(phase_high, dtype=np.float64)
    if np.any(~np.isfinite(phi[valid])):
        raise UnwrapError("phase_high is not finite at pixels marked valid")
    return cost, phi, valid, wx, wy


def _pairs(idx, phi, n, wx, wy, extra_edges):
    """(P, Q, w, m): node indices of the pairs with w > 0 and their jump offsets
    ``m = round((phi_p - phi_q) / 2 pi) + n_p - n_q``."""
    H, W = idx.shape
    pi_, qi_, ws, ms = [], [], [], []
    for w, axis in ((wx, 1), (wy, 0)):
        p = idx[:, :-1] if axis == 1 else idx[:-1, :]
        q = idx[:, 1:] if axis == 1 else idx[1:, :]
        dphi = -np.diff(phi, axis=axis)                          # phi_p - phi_q
        m = np.rint(dphi / TWO_PI).astype(np.int64) + (n[:, :-1] - n[:, 1:] if axis == 1 else n[:-1, :] - n[1:, :])
        keep = (p >= 0) & (q >= 0) & (w > 0)
        pi_.append(p[keep]), qi_.append(q[keep]), ws.append(w[keep]), ms.append(m[keep])
    if extra_edges is not None:
        fp, fq, fw = (np.asarray(a).reshape(-1) for a in extra_edges)
        if not (fp.shape == fq.shape == fw.shape) or (fp.size and (min(fp.min(), fq.min()) < 0
                                                                   or max(fp.max(), fq.max()) >= H * W)):
            raise UnwrapError("extra_edges: p, q, w must have one length and index pixels of the image")
        if not np.all(np.isfinite(fw)) or (fw < 0).any():
            raise UnwrapError("extra_edges: weights must be finite and >= 0")
        fp, fq = fp.astype(np.int64), fq.astype(np.int64)
        ip, iq = idx.reshape(-1)[fp], idx.reshape(-1)[fq]
        phf, nf = phi.reshape(-1), n.reshape(-1)
        m = np.rint((phf[fp] - phf[fq]) / TWO_PI).astype(np.int64) + nf[fp] - nf[fq]
        keep = (ip >= 0) & (iq >= 0) & (fw > 0)
        pi_.append(ip[keep]), qi_.append(iq[keep]), ws.append(fw[keep]), ms.append(m[keep])
    return tuple(np.concatenate(a) for a in (pi_, qi_, ws, ms))


def _min_cut_labels(D, P, Q, Wt, M):
    """Labels 0..L-1 (N,) minimising sum D[a_p, p] + sum w |a_p - a_q + m| (Ishikawa's graph)."""
    import maxflow

    L, n_valid = D.shape
    M = np.clip(M, -(L - 1), L - 1)       # |m| >= L - 1: the term is linear in the labels, the same for all such m
    delta = np.diff(D, axis=0)
    src = np.maximum(delta, 0.0)          # paid when u = 1 (sink side)
    snk = np.maximum(-delta, 0.0)         # paid when u = 0
    g = maxflow.Graph[float](n_valid * (L - 1), 4 * n_valid * (L - 1))
    nodes = g.add_nodes(n_valid * (L - 1))
    ids = np.asarray(nodes).reshape(L - 1, n_valid) if np.ndim(nodes) else \
        np.arange(n_valid * (L - 1)).reshape(L - 1, n_valid)
    # |a_p - a_q + m| = sum_i |[a_p > i] - [a_q > i + m]|, [a > i] = 1 for i < 0 and 0 for i > L - 2
    ei, ej, ew = [], [], []
    for i in range(-(L - 1), 2 * (L - 1)):
        j = i + M
        q_in = (j >= 0) & (j <= L - 2)
        if 0 <= i <= L - 2:
            ei.append(ids[i, P[q_in]]), ej.append(ids[j[q_in], Q[q_in]]), ew.append(Wt[q_in])
            lo, hi = j < 0, j > L - 2         # q's indicator is 1 (lo) or 0 (hi): |u_i - 1| or |u_i|
            _add_unary(snk, i, P[lo], Wt[lo])
            _add_unary(src, i, P[hi], Wt[hi])
        else:                                 # p's indicator is 1 (i < 0) or 0 (i > L - 2)
            _add_unary(snk if i < 0 else src, j[q_in], Q[q_in], Wt[q_in])
    a, b, w = np.concatenate(ei), np.concatenate(ej), np.concatenate(ew)
    if a.size:
        g.add_edges(a, b, w, w)
    for i in range(L - 2):                    # monotone layers: u_i >= u_{i+1}
        g.add_edges(ids[i], ids[i + 1], np.full(n_valid, _INF), np.zeros(n_valid))
    g.add_grid_tedges(ids, src, snk)
    g.maxflow()
    return g.get_grid_segments(ids).sum(axis=0)  # u = 1 on the sink side; label = number of layers at 1


def solve_corrections(cost, phase_high, order, valid, wx, wy, extra_edges=None):
    """Exact minimiser of the energy of the module docstring.

    ARGUMENTS: cost (L, H, W) float64 nats (L = 2 K + 1 labels, index c + K; finite at valid
    pixels); phase_high (H, W) wrapped high-frequency phase (rad); order (H, W) traditional
    order; valid (H, W) bool; wx (H, W-1), wy (H-1, W) smoothness weights (nats per jump, >= 0);
    extra_edges: optional (p, q, w) of more pairs (flat row-major pixel indices, e.g.
    :func:`bridge_edges`; pairs with an invalid pixel are ignored).
    RETURNED VALUE: (correction (H, W) int64, 0 at invalid pixels; the energy of that solution
    (float, nats)).
    """
    cost, phi, valid, wx, wy = _check_solver_inputs(cost, phase_high, order, valid, wx, wy)
    L, H, W = cost.shape
    n_valid = int(valid.sum())
    out = np.zeros((H, W), dtype=np.int64)
    if n_valid == 0:
        return out, 0.0
    idx = np.full((H, W), -1, dtype=np.int64)
    idx[valid] = np.arange(n_valid)
    n = np.where(valid, np.asarray(order, dtype=np.int64), 0)
    P, Q, Wt, M = _pairs(idx, np.where(valid, phi, 0.0), n, wx, wy, extra_edges)
    D = cost[:, valid]                                          # (L, N)
    a = _min_cut_labels(D, P, Q, Wt, M)
    out[valid] = a - L // 2
    energy = D[a, np.arange(n_valid)].sum() + (Wt * np.abs(M + a[P] - a[Q])).sum()
    return out, float(energy)


@dataclass
class SpatialResult:
    """Output of :func:`graphcut_orders` (camera image shape)."""
    order: np.ndarray                 # int64, -1 invalid: traditional order + correction
    order_traditional: np.ndarray     # int64, -1 invalid
    correction: np.ndarray            # int64, 0 invalid
    prior: np.ndarray                 # float64, 0 invalid
    p_wrong_traditional: np.ndarray   # float64 in [0, 1], the reliability model's (noise only)
    valid: np.ndarray
    energy: float
    seconds: float


def graphcut_orders(method: str, phase_low, phase_high, frequencies, valid, sigma_phase_low, sigma_phase_high, *,
                    width: float, cost=None, smoothness: float | None = None, outlier: float | None = None,
                    sigma_floor: float | None = None, max_correction: int = MAX_CORRECTION, modulation=None,
                    min_modulation: float = 0.0, max_wrapped_step: float = math.pi / 2,
                    max_prior_step: float = 1.5, bridge: bool = True, bias_bound=None,
                    bias_scale: float | None = None, step_odds: float | None = None) -> SpatialResult:
    """Fringe orders of the high frequency of one orientation by the spatial energy (module docstring).

    ARGUMENTS: method "mf" | "mw" | "nt"; wrapped phases (rad, (H, W), NaN allowed where invalid);
    frequencies (low, high) in periods across ``width`` projector pixels; valid (H, W) bool;
    sigma_phase_low / high: phase noise (rad, scalar or (H, W); :func:`phase_noise`);
    ``cost``: a data term (L, H, W) in nats to use instead of the prior's (the learned path:
    ``-log p``); ``smoothness``: nats per 2 pi jump between neighbours; ``outlier``, ``sigma_floor``
    (fringes, added in quadrature to the prior's noise): the prior's likelihood (None: :data:`DEFAULTS`;
    the smoothness default is ``smoothness_learned`` when ``cost`` is given); the rest: see
    :func:`edge_weights` (``modulation``, ``min_modulation`` in the same units); ``bridge``: add
    :func:`bridge_edges` for pixels with fewer than 2 valid 4-neighbours. ``bias_bound``: (H, W)
    the bound on the prior's bias from global light (fringes of the high frequency,
    :meth:`unwrap.global_light.GlobalBias.fringes`); the prior's likelihood then gets a bias spread
    ``bias_scale * bias_bound`` (None: :data:`DEFAULTS` ``bias_scale``) in quadrature with its noise
    (``prior_data_cost``'s ``bias_sigma``). None (default): the data term without it, as before.
    ``step_odds``: the smoothness of each edge is scaled by the probability that its pixels lie on
    one surface given the prior's step (:mod:`unwrap.spatial_edges`; 0: off). None: :data:`DEFAULTS`
    ``step_odds`` with the prior's data term, 0 with a given ``cost`` (not calibrated for it).
    """
    from .temporal import decode_pair as traditional

    t0 = time.perf_counter()
    if smoothness is None:
        smoothness = DEFAULTS["smoothness" if cost is None else "smoothness_learned"]
    outlier = DEFAULTS["outlier"] if outlier is None else outlier
    sigma_floor = DEFAULTS["sigma_floor"] if sigma_floor is None else sigma_floor
    maps = {"phase_low": phase_low, "phase_high": phase_high, "valid": valid}
    H, W = _check_maps(maps)
    phi_lo, phi_hi = (np.asarray(a, dtype=np.float64) for a in (phase_low, phase_high))
    valid = np.asarray(valid, dtype=bool)
    if np.any(valid & ~(np.isfinite(phi_lo) & np.isfinite(phi_hi))):
        raise UnwrapError("graphcut_orders: a wrapped phase is NaN or infinite at pixels marked valid; "
                          "clear them from valid first")
    f_lo, f_hi = (float(f) for f in frequencies)
    prior, n, ok = traditional(method, np.nan_to_num(phi_lo), np.nan_to_num(phi_hi), f_lo, f_hi, float(width), valid)
    sig = np.sqrt(prior_sigma(method, (f_lo, f_hi), sigma_phase_low, sigma_phase_high) ** 2 + sigma_floor ** 2)
    sig = np.broadcast_to(sig, (H, W))
    if np.any(ok & ~(np.isfinite(sig) & (sig > 0))):
        raise UnwrapError("graphcut_orders: the phase noise must be finite and > 0 at valid pixels")
    p_wrong = traditional_error_probability(prior, n, sig, ok, max_correction=max_correction)
    given_cost = cost
    if cost is not None and bias_bound is not None:
        raise UnwrapError("graphcut_orders: bias_bound widens the prior's data term; it cannot act on a given cost")
    if cost is None:
        bias_sigma = None
        if bias_bound is not None:
            _check_maps({"phase_low": phase_low, "bias_bound": bias_bound})
            scale = DEFAULTS["bias_scale"] if bias_scale is None else float(bias_scale)
            if not (math.isfinite(scale) and scale >= 0):
                raise UnwrapError(f"bias_scale must be finite and >= 0, got {bias_scale!r}")
            bias_sigma = scale * np.asarray(bias_bound, dtype=np.float64)
        cost = prior_data_cost(prior, n, sig, ok, frequency_high=f_hi, max_correction=max_correction, outlier=outlier,
                               bias_sigma=bias_sigma)
    else:
        cost = np.asarray(cost, dtype=np.float64)
        if cost.shape != (2 * max_correction + 1, H, W):
            raise UnwrapError(f"cost {cost.shape}: expected ({2 * max_correction + 1}, {H}, {W})")
        k = n[None] + _labels(max_correction)[:, None, None]
        cost = np.where((k < 0) | (k > math.floor(f_hi + 0.5)), OUT_OF_RANGE_COST, cost)
    wx, wy = edge_weights(phi_hi, ok, weight=smoothness, prior=prior, modulation=modulation,
                          min_modulation=min_modulation, max_wrapped_step=max_wrapped_step,
                          max_prior_step=max_prior_step)
    extra = bridge_edges(phi_hi, ok, weight=smoothness, prior=prior, max_wrapped_step=max_wrapped_step,
                         max_prior_step=max_prior_step) if bridge else None
    wx, wy, extra = scale_weights(wx, wy, extra, prior, phi_hi, sig, outlier=outlier, odds=(
        step_odds if step_odds is not None else DEFAULTS["step_odds"] if given_cost is None else 0.0))
    c, energy = solve_corrections(cost, phi_hi, n, ok, wx, wy, extra)
    order = np.where(ok, n + c, -1)
    return SpatialResult(order.astype(np.int64), n.astype(np.int64), c, np.where(ok, prior, 0.0), p_wrong, ok,
                         energy, time.perf_counter() - t0)


def gate(order, order_traditional, valid, p_wrong_traditional, *, confidence=None, min_confidence: float = 0.0,
         min_p_wrong: float = 0.0) -> np.ndarray:
    """Never-worse gate: keep ``order`` (a learned or spatial decision) only where it differs from
    the traditional order, the traditional decision is unreliable (``p_wrong_traditional >=
    min_p_wrong``; the shipped :data:`GATE` thresholds are for
    :func:`unwrap.decision_error.error_probability`, which knows bias) and the decision is sure
    (``confidence >= min_confidence``, when given); elsewhere the traditional order. (H, W) int64,
    -1 invalid."""
    _check_maps({"order": order, "order_traditional": order_traditional, "valid": valid,
                 "p_wrong_traditional": p_wrong_traditional})
    apply = np.asarray(p_wrong_traditional, dtype=np.float64) >= min_p_wrong
    if confidence is not None:
        apply &= np.asarray(confidence, dtype=np.float64) >= min_confidence
    out = np.where(apply, order, order_traditional)
    return np.where(np.asarray(valid, dtype=bool), out, -1).astype(np.int64)


__all__ = ["DEFAULTS", "GATE", "MAX_CORRECTION", "SpatialResult", "bridge_edges", "edge_weights", "gate", "graphcut_orders", "phase_noise",
           "prior_data_cost", "prior_sigma", "solve_corrections", "traditional_error_probability"]
