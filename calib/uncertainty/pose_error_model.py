"""Parameter uncertainty when the observations of one pose share errors: per-pose error fields.

The adjustment's covariance ``sigma^2 (J^T J)^-1`` treats every residual as independent. On real
sessions they are not: a pose's residuals share a shift and a tilt across the board (measured on
the SLStudio session: neighbouring corners' residuals correlate 0.3-0.5, and the projector's row
residuals of one pose 0.6-0.9 at any distance - the projector image does not sit at the same place
relative to the camera at every pose, corner detection errors depend on the pose's lighting...). Those
shared errors do not average out over a pose's hundred points, so the independent model understates
the uncertainty (there by 2-9x against a leave-one-pose-out spread).

Model (whitened residuals ``e`` of :mod:`calib.adjustment.jacobian`):

    e = n + sum_l A_l c_l

- ``n``: independent errors, variance ``s0`` each;
- for every device d, coordinate (u, v) and basis function b in {1, x, y} (board coordinates over
  the board's half-extent): ``A_l`` (m, n_poses) holds b at that device's, coordinate's rows of
  each pose, and ``c_l`` (n_poses,) the pose's random coefficient, variance ``S_l``, independent
  across poses and components. An affine error field per pose and device: what a drifting
  projector image, a pose-dependent detection bias or a per-pose board placement error leave.

Estimation (restricted method of moments): the residuals are ``r = (I - H) e`` (H the hat matrix
``J (J^T J)^-1 J^T``: the fit absorbs part of every field), so for the statistics
``T_l = |A_l^T r|^2`` and ``T_0 = r.r``

    E[T_k] = sum_l S_l |A_k^T (I - H) A_l|_F^2 + s0 trace(A_k^T (I - H) A_k),
    E[T_0] = sum_l S_l |(I - H) A_l|_F^2 + s0 (m - n),

solved for ``S >= 0``, ``s0 >= 0`` by non-negative least squares (each equation weighted by its
statistic's scatter under independent errors), keeping only the fields whose statistic stands out of what the rest explains by more
than 3.5 of its standard deviations (a field per device, coordinate and basis function would
otherwise fit the statistics' own scatter). Without shared errors no field is kept and the
covariance is the adjustment's.

Covariance (sandwich: the estimate stays the least-squares one, the errors are not what it assumed):

    cov = B J^T Omega J B,   B = (J^T J)^-1,   Omega = s0 I + sum_l S_l A_l A_l^T,

each parameter's variance then multiplied by the factor for levels estimated from few poses
(:mod:`calib.uncertainty.level_uncertainty`: ``E[v / v_hat]``, a Student-t inflation; 1 without kept fields).

Checked: on the SLStudio session the standard deviations it gives are those of a bootstrap over
poses (ratio median 1.13, 0.74-1.73 over the 24 intrinsics and rig parameters) where the
independent model's are 3-9x too small (docs/calib.md, "Honest uncertainty"); on simulated data
with a known error field it reproduces the spread of the estimates (tests/test_pose_error_model.py).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse

from ..errors import UncertaintyError
from .level_uncertainty import level_uncertainty
from .nnls import nnls

SIGNIFICANCE = 3.5
"""A field is kept when its statistic exceeds what the rest explains by this many standard deviations."""

BASIS = ("1", "x", "y")
"""The per-pose error field's basis over the board (board coordinates scaled to [-1, 1])."""


@dataclass
class PoseErrorModel:
    """Estimated error model and the covariance it gives.

    - names (G,): global parameters (intrinsics, distortion, rig, warp); std / std_independent:
      {name: 1-sigma} with the model and with independent residuals (the adjustment's).
    - cov (G, G): covariance of the global parameters under the model.
    - independent_fraction: ``s0`` over the mean squared whitened residual (1: no shared error).
    - fields: {"camera.u.1": sd, ...} the per-pose field coefficients' standard deviations in
      pixels (basis "1": a shift; "x"/"y": change across the board's half-extent).
    """

    names: list
    std: dict
    std_independent: dict
    cov: np.ndarray
    independent_fraction: float
    fields: dict
    components: tuple = None
    """(labels, S, s0): the fields' labels, their per-pose coefficient variances (whitened units;
    0: not kept) and the independent variance, for checks that rebuild ``Omega``."""
    levels: object = None
    """:class:`calib.uncertainty.level_uncertainty.LevelUncertainty`: the sigmas above are already multiplied by
    its ``inflation`` (few poses: the per-pose levels are themselves uncertain)."""

    def inflation(self) -> dict:
        """{name: std / std_independent}."""
        return {n: self.std[n] / self.std_independent[n] for n in self.names if self.std_independent[n] > 0}


def _field_matrices(aj, obs) -> tuple[list, list, np.ndarray]:
    """Per-pose field bases over the inlier rows: ([A_l (m_in, n_poses) sparse CSC], [label], inlier
    rows). Each row of an A_l has one non-zero at most (its pose's column)."""
    rows = np.flatnonzero(np.repeat(aj.inlier, 2))
    pos = np.full(2 * len(aj.inlier), -1)
    pos[rows] = np.arange(len(rows))
    allX = np.concatenate([v.points_board for v in obs.views])[:, :2]
    mid, half = (allX.max(0) + allX.min(0)) / 2, np.maximum((allX.max(0) - allX.min(0)) / 2, 1e-9)
    xy = np.empty((len(aj.inlier), 2))
    for i, v in enumerate(obs.views):
        at = aj.view == i
        xy[at] = (v.points_board[aj.index[at], :2] - mid) / half
    mats, labels = [], []
    for d in ("camera", "projector"):
        pts = np.flatnonzero((aj.device == d) & aj.inlier)
        for c, coord in enumerate("uv"):
            for b, name in enumerate(BASIS):
                val = np.ones(len(pts)) if b == 0 else xy[pts, b - 1]
                keep = val != 0
                A = scipy.sparse.csc_matrix((val[keep], (pos[2 * pts[keep] + c], aj.view[pts[keep]])),
                                            shape=(len(rows), len(obs.views)))
                if A.nnz:
                    mats.append(A)
                    labels.append(f"{d}.{coord}.{name}")
    return mats, labels, rows


def fit_pose_error_model(aj, obs) -> PoseErrorModel:
    """Estimate the per-pose error fields from the residuals and return the covariance they give
    (module docstring). ``aj``: :func:`calib.adjustment.jacobian.adjustment_jacobian` of the
    calibration of ``obs``.

    Computed without any (m x n_poses) or (m x m) dense matrix: with ``P_l = J^T A_l`` and
    ``Q_l = B P_l`` (n x n_poses), ``A_k^T (I - H) A_l = A_k^T A_l - P_k^T Q_l`` and
    ``|(I - H) A_l|_F^2 = trace(A_l^T (I - H) A_l) = |A_l|_F^2 - sum(P_l * Q_l)`` (I - H is a
    symmetric projection); the sparse ``J`` and ``A_l`` make it O(points x parameters)."""
    mats, labels, rows = _field_matrices(aj, obs)
    J, r = aj.J[rows], aj.r[rows]
    m, n = J.shape
    if m - n < 2 * len(mats) or len(obs.views) < 3:
        raise UncertaintyError(f"{m} residuals for {n} parameters and {len(obs.views)} pose(s): too few to "
                               "estimate per-pose error fields")
    B = aj.normal_inverse                 # outliers' rows of J are 0: J^T J over the inliers is J's
    L, V = len(mats), len(obs.views)
    # every field side by side: one sparse and two dense products instead of L^2 small ones
    A = scipy.sparse.hstack(mats).tocsc()                         # (m, L n_poses)
    P_all = (J.T.tocsr() @ A).toarray()                            # J^T A_l (n, n_poses) side by side
    lever_all = B @ P_all                                          # (J^T J)^-1 J^T A_l
    cross_all = (A.T @ A).toarray() - P_all.T @ lever_all          # A_k^T (I - H) A_l, (n_poses, n_poses) blocks
    block = [slice(l * V, (l + 1) * V) for l in range(L)]
    lever = [lever_all[:, b] for b in block]
    cross = [[cross_all[bk, bl] for bl in block] for bk in block]
    trace = [float(Al.multiply(Al).sum()) - float(np.sum(P_all[:, b] * lever_all[:, b])) for Al, b in zip(mats, block)]
    M = np.zeros((L + 1, L + 1))
    T = np.zeros(L + 1)
    T[:-1] = ((A.T @ r) ** 2).reshape(L, V).sum(axis=1)
    M[:-1, :-1] = (cross_all ** 2).reshape(L, V, L, V).sum(axis=(1, 3))
    M[:-1, -1] = trace                                             # trace(A^T (I - H) A)
    T[-1] = r @ r
    M[-1, :-1] = trace                                             # |(I - H) A_l|_F^2
    M[-1, -1] = m - n
    S, s0 = _solve_components(M, T)
    g = aj.global_index
    # the covariance of the global parameters only (the poses' is not reported); fields not kept add 0
    cov = s0 * B[np.ix_(g, g)] + sum(s * Q[g] @ Q[g].T for s, Q in zip(S, lever) if s > 0)
    names = [aj.names[k] for k in g]
    levels = level_uncertainty(S, s0, cross, lever, B, g, labels)
    cov_g = cov * np.outer(levels.inflation, levels.inflation)
    cov_ind = aj.sigma2 * B[np.ix_(g, g)]          # outliers' rows of J are 0: J^T J over the inliers is J's
    px = _whitening_px(aj)
    fields = {lab: float(np.sqrt(s)) * px[lab.split(".")[0]] for lab, s in zip(labels, S)}
    return PoseErrorModel(names, dict(zip(names, np.sqrt(np.diag(cov_g)).tolist())),
                          dict(zip(names, np.sqrt(np.diag(cov_ind)).tolist())), cov_g,
                          float(s0 / max(np.mean(r ** 2), 1e-300)), fields, (labels, S, float(s0)), levels)


def _solve_components(M, T) -> tuple[np.ndarray, float]:
    """Non-negative variance components from the moment equations ``M [S, s0] = T`` by forward
    selection: starting from independent errors alone, the field whose statistic stands out most
    from what the model so far explains is added while that excess exceeds ``SIGNIFICANCE``
    standard deviations (``Var T_k = 2 s0^2 |A_k^T (I - H) A_k|_F^2`` under Gaussian errors). With
    one free variance per field and no selection the equations would fit the statistics' own
    scatter (a 6-pose statistic scatters by ~60 %) and inflate every sigma."""
    n = len(T) - 1
    active = np.zeros(n, bool)
    # each equation weighted by its statistic's scatter under independent errors (per unit s0):
    # the total (m - n degrees of freedom) pins s0, a 6-pose field statistic much less
    weight = 1.0 / np.sqrt(2.0 * np.maximum(np.r_[np.diag(M)[:n], M[n, n]], 1e-300))
    while True:
        cols = np.r_[np.flatnonzero(active), n]
        sol, _ = nnls(M[:, cols] * weight[:, None], T * weight)
        S = np.zeros(n)
        S[cols[:-1]] = sol[:-1]
        s0 = sol[-1]
        excess = (T[:n] - M[:n, :n] @ S - M[:n, n] * s0) / np.maximum(s0 * np.sqrt(2 * np.diag(M)[:n]), 1e-300)
        excess[active] = -np.inf
        k = int(np.argmax(excess))
        if active.all() or excess[k] <= SIGNIFICANCE:
            return S, s0
        active[k] = True


def _whitening_px(aj) -> dict:
    """Pixels behind one whitened unit, per device (median over its points)."""
    return {d: float(np.nanmedian(aj.px_per_unit[aj.device == d])) if np.any(aj.device == d) else 1.0
            for d in ("camera", "projector")}
