"""The adjustment's whitened residuals and their Jacobian, recomputed from the solution: the input
of every uncertainty that looks beyond the adjustment's own "independent residuals" model.

``calib.adjustment.solver`` reports ``sigma^2 (J^T J)^-1``, which assumes every residual independent. To
ask what the parameters' uncertainty is when the residuals are correlated (within a pose, across
the board) one needs ``J`` and the residuals themselves. They are rebuilt here from the solution
(:class:`calib.calibrate.Calibration`) and the observations, in the adjustment's own terms (joint
mode, DESIGN.md frames): by default with the adjustment's compiled kernel, which gives the exact
derivatives in one pass over the points (``method="analytic"``); or, as an independent check, with
:class:`calib.device.DeviceModel` projections and central differences (``method="differences"``,
one residual evaluation per parameter and side: 1253 at 100 views). The two agree to ~5e-7 relative
in the sigmas they give, the differences' rounding (a test). The model:

- camera point k of view i: ``r = (q_cam(R_i X_k + t_i) - q_obs) / sigma_k``;
- projector point: ``r = (q_prj(R_pc (R_i X_k + t_i) + t_pc) - q_obs - A_k r_cam,k) / sigma_k``
  (``A_k`` = ``dprj_dcam``, the camera error transfer, where the adjustment used it);
- each device's rows scaled by ``1 / s_d`` (``s_d^2`` the mean squared residual of its inliers,
  the adjustment's device weighting), outliers weighted 0;
- board points ``X_k`` with the optional warp ``z += c_x (1 - xn^2) + c_y (1 - yn^2)``;
- parameters: the adjustment's free parameters by name (``camera.fx``, ``prj_cam.w0`` (tangent,
  ``R = R0 Exp(w)``), ``cam_board/3.t2``, ``board_warp.cx``, ...).

:func:`adjustment_jacobian` checks itself: ``sigma^2 (J^T J)^-1`` must reproduce the adjustment's
reported standard deviations (to 1 %); when it does not (a model this module does not rebuild:
single-device mode, a robust loss), it refuses (:class:`calib.errors.UncertaintyError`) rather than
feed a different model's Jacobian to the uncertainty.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse

from ..device import DeviceModel
from ..errors import UncertaintyError
from ..rotation import matrix_from_rotvec

INTRINSICS = ("fx", "fy", "cx", "cy", "skew")
DISTORTION = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4")
SELF_CHECK_RTOL = 0.01


@dataclass
class AdjustmentJacobian:
    """Whitened, weighted residuals of a solved adjustment and their Jacobian.

    - names (n,): free parameters; J (m, n) ``scipy.sparse.csr_matrix``: d r / d parameter (rows:
      point k coordinate c at row 2 k + c; a board pose's columns are non-zero on its view's rows
      only); r (m,): residuals at the solution (0 for outliers).
    - view, device, index (P,): the view, device and point index (into the view's board points)
      of each of the P = m / 2 points; inlier (P,) bool.
    - sigma2: residual variance ``r.r / (2 inliers - n)``; global_index: the parameters other
      than board poses.
    - px_per_unit (P,): pixels behind one whitened unit of each point (its sigma over its
      device's weight).
    """

    names: list
    J: np.ndarray
    r: np.ndarray
    view: np.ndarray
    device: np.ndarray
    index: np.ndarray
    inlier: np.ndarray
    sigma2: float
    px_per_unit: np.ndarray

    @property
    def global_index(self) -> np.ndarray:
        return np.array([k for k, n in enumerate(self.names) if "/" not in n], dtype=int)

    @cached_property
    def normal_inverse(self) -> np.ndarray:
        """``(J^T J)^-1`` (n, n), computed once and shared by :meth:`covariance` (the self-check)
        and the per-pose error model (:mod:`calib.uncertainty.pose_error_model`)."""
        return np.linalg.inv((self.J.T @ self.J).toarray())

    def covariance(self) -> np.ndarray:
        """The adjustment's model: ``sigma^2 (J^T J)^-1`` (n, n)."""
        return self.sigma2 * self.normal_inverse


def _parameters(state) -> dict:
    p = {}
    for d in state.K:
        K = state.K[d]
        p.update({f"{d}.{n}": v for n, v in zip(INTRINSICS, (K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]))})
        p.update({f"{d}.{n}": float(v) for n, v in zip(DISTORTION, state.dist[d])})
    for pn, (_, t) in state.poses.items():
        p.update({f"{pn}.w{j}": 0.0 for j in range(3)})
        p.update({f"{pn}.t{j}": float(t[j]) for j in range(3)})
    p["board_warp.cx"], p["board_warp.cy"] = (float(w) for w in state.warp)
    return p


class _Model:
    """The adjustment's residual function of a parameter dictionary (module docstring)."""

    def __init__(self, cal, obs):
        self.state, self.obs = cal.ba.state, obs
        allX = np.concatenate([v.points_board for v in obs.views])
        self.half = np.maximum((allX[:, :2].max(0) - allX[:, :2].min(0)) / 2, 1e-9)
        self.mid = (allX[:, :2].max(0) + allX[:, :2].min(0)) / 2

    def device(self, p, d):
        K = [[p[f"{d}.fx"], p[f"{d}.skew"], p[f"{d}.cx"]], [0.0, p[f"{d}.fy"], p[f"{d}.cy"]], [0.0, 0.0, 1.0]]
        dist = [p[f"{d}.{n}"] for n in DISTORTION[:len(self.state.dist[d])]]
        key = (d, tuple(K[0]), tuple(K[1]), tuple(dist))
        cache = self.__dict__.setdefault("_devices", {})
        if key not in cache:                 # a pose's differences keep the devices: built once
            if len(cache) > 8:
                cache.clear()
            cache[key] = DeviceModel(size=self.obs.sizes[d], K=K, distortion=dist, kind=d)
        return cache[key]

    def pose(self, p, name):
        R0 = self.state.poses[name][0]
        return (R0 @ matrix_from_rotvec(np.array([p[f"{name}.w{j}"] for j in range(3)])),
                np.array([p[f"{name}.t{j}"] for j in range(3)]))

    def residuals(self, p, transfer: bool, views=None) -> np.ndarray:
        """(P, 2) residuals divided by each point's sigma, in the order of :func:`point_order`
        (``views``: only those views' points, in the same order). All views' points are projected
        by one call per device."""
        cam, prj = self.device(p, "camera"), self.device(p, "projector")
        R_pc, t_pc = self.pose(p, "prj_cam")
        sel = [i for i in range(len(self.obs.views)) if views is None or i in views]
        X_cam = []
        for i in sel:
            v = self.obs.views[i]
            R, t = self.pose(p, f"cam_board/{i}")
            X = v.points_board.copy()
            xn, yn = (X[:, 0] - self.mid[0]) / self.half[0], (X[:, 1] - self.mid[1]) / self.half[1]
            X[:, 2] += p["board_warp.cx"] * (1 - xn ** 2) + p["board_warp.cy"] * (1 - yn ** 2)
            X_cam.append(X @ R.T + t)
        ends = np.cumsum([len(X) for X in X_cam])
        allX = np.concatenate(X_cam)
        q_cam = np.split(cam.project_device(allX), ends[:-1])
        q_prj = np.split(prj.project_device(allX @ R_pc.T + t_pc), ends[:-1])
        out = []
        for i, qc, qp in zip(sel, q_cam, q_prj):
            v = self.obs.views[i]
            r_cam = qc - v.q.get("camera", np.nan)
            r_prj = qp - v.q.get("projector", np.nan)
            if transfer and v.dprj_dcam is not None:
                link = v.seen("camera") & np.all(np.isfinite(v.dprj_dcam), axis=(1, 2))
                moved = np.einsum("kij,kj->ki", np.nan_to_num(v.dprj_dcam), np.nan_to_num(r_cam))
                r_prj = np.where(link[:, None], r_prj - moved, r_prj)
            for d, r in (("camera", r_cam), ("projector", r_prj)):
                if d in v.q:
                    out.append((r / v.sigma[d][:, None])[v.seen(d)])
        return np.concatenate(out)


def point_order(obs):
    """(view (P,), device (P,), index (P,)) of the adjustment's points: views in order, the camera's
    points then the projector's, each in board-point order."""
    blocks = [(i, d, np.flatnonzero(v.seen(d))) for i, v in enumerate(obs.views) for d in ("camera", "projector")
              if d in v.q]
    if not blocks:
        return np.zeros(0, int), np.zeros(0, "<U9"), np.zeros(0, int)
    return (np.concatenate([np.full(len(k), i) for i, _, k in blocks]),
            np.concatenate([np.full(len(k), d, dtype="<U9") for _, d, k in blocks]),
            np.concatenate([k for _, _, k in blocks]))


def _point_ids(obs, view, index) -> np.ndarray:
    """(P,) board feature id of each point of :func:`point_order` (``index`` into its view's ids)."""
    if len(view) == 0:
        return np.zeros(0, dtype=np.int64)
    sizes = [len(v.ids) for v in obs.views]
    start = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    every = np.concatenate([np.asarray(v.ids, dtype=np.int64) for v in obs.views])
    return every[start[np.asarray(view)] + np.asarray(index)]


def _step(name: str, value: float) -> float:
    if ".w" in name:
        return 1e-7                      # rad
    if ".t" in name or name.startswith("board_warp"):
        return 1e-5                      # mm
    return 1e-6 * max(1.0, abs(value))


def adjustment_jacobian(cal, obs, *, method: str = "analytic") -> AdjustmentJacobian:
    """Rebuild the residuals and Jacobian of ``cal`` (a joint :class:`calib.calibrate.Calibration`
    of ``obs``), checked against the adjustment's own standard deviations (module docstring).

    ``method``: "analytic" (default): the adjustment's own compiled kernel evaluated once at the
    solution (:meth:`calib.adjustment.problem.BAProblem.evaluate`: exact derivatives, one pass over
    the points); "differences": central differences of this module's independent rebuild of the
    model with :class:`calib.device.DeviceModel` projections (one residual evaluation per
    parameter and side; the cross-check of the analytic one, and what a calibration without its
    ``config`` gets: they agree to ~1e-7 in the sigmas, a test)."""
    ba = cal.ba
    if ba.mode != "joint" or "prj_cam" not in ba.state.poses:
        raise UncertaintyError("the error model needs a joint camera + projector adjustment")
    config = getattr(cal, "config", None)
    loss = getattr(config, "loss", "linear")
    if loss != "linear":
        raise UncertaintyError(f"the error model needs the linear loss (the adjustment used {loss!r})")
    if method not in ("analytic", "differences"):
        raise UncertaintyError(f"method: expected 'analytic' or 'differences', got {method!r}")
    view, device, index = point_order(obs)
    ids = _point_ids(obs, view, index)
    if np.array_equal(ba.point_view, view) and np.array_equal(ba.point_device, device) and \
            np.array_equal(ba.point_id, ids):
        inlier = np.asarray(ba.inlier, bool).copy()      # the adjustment laid its points out in this order
    else:
        key = {(int(v), str(d), int(i)): bool(ok) for v, d, i, ok in
               zip(ba.point_view, ba.point_device, ba.point_id, ba.inlier)}
        inlier = np.array([key.get((int(v), str(d), int(i)), False) for v, d, i in zip(view, device, ids)])
    p0 = _parameters(ba.state)
    names = [n for n in ba.free_names if n in p0]
    if len(names) != len(ba.free_names):
        raise UncertaintyError(f"parameters the error model does not know: {sorted(set(ba.free_names) - set(p0))}")
    if method == "analytic" and config is not None:      # (without its config the layout is unknown)
        r0, J = _analytic(cal, obs, names, view, device, ids)
    else:
        r0, J = _differences(cal, obs, names, view, p0, getattr(config, "camera_error_transfer", True))
    weight = np.zeros(len(r0))
    for d in ("camera", "projector"):
        m = (device == d) & inlier
        if m.any():
            weight[device == d] = 1.0 / np.sqrt(np.mean(r0[m] ** 2))
    sigma = np.concatenate([v.sigma[d][v.seen(d)] for v in obs.views for d in ("camera", "projector") if d in v.q])
    px_per_unit = sigma / np.where(weight > 0, weight, np.nan)
    weight *= inlier
    rows = np.repeat(weight, 2)
    J = scipy.sparse.csr_matrix(scipy.sparse.diags(rows) @ J)
    J.eliminate_zeros()
    r = (r0 * weight[:, None]).ravel()
    out = AdjustmentJacobian(names, J, r, view, device, index, inlier, float(r @ r) / (2 * inlier.sum() - len(names)),
                             px_per_unit)
    _self_check(out, ba)
    return out


def _analytic(cal, obs, names, view, device, ids):
    """(residuals over their sigmas (P, 2), their Jacobian (2 P, n) sparse) at the solution, from
    the adjustment's own kernel (the same function it minimised: camera error transfer, warp and
    rotation increments as it has them)."""
    from dataclasses import replace

    from .problem import build_problem

    problem = build_problem(obs, cal.ba.state, replace(cal.config, progress=None))
    free = [n for n, f in zip(problem.names, problem.free) if f]
    if free != names or not (np.array_equal(problem.point_view, view) and np.array_equal(problem.point_device, device)
                             and np.array_equal(problem.point_id, ids)):
        raise UncertaintyError("the adjustment's layout is not the error model's point order")
    ev = problem.evaluate(problem.start)
    rows = (2 * problem.point_pad[:, None] + np.arange(2)).ravel()      # the points' padded rows, in order
    scale = problem.inv_sigma_rows[rows][:, None]
    Jg, Jv = ev.Jg[rows] * scale, ev.Jv[rows] * scale                   # (2 P, G_free), (2 P, 6)
    Gf = Jg.shape[1]
    slot = np.repeat(problem.point_pad // problem.P_max, 2)
    m = len(rows)
    ri = np.r_[np.repeat(np.arange(m), Gf), np.repeat(np.arange(m), 6)]
    ci = np.r_[np.tile(np.arange(Gf), m), (Gf + 6 * slot[:, None] + np.arange(6)).ravel()]
    J = scipy.sparse.csr_matrix((np.r_[Jg.ravel(), Jv.ravel()], (ri, ci)), shape=(m, len(names)))
    return ev.r[rows].reshape(-1, 2), J


def _differences(cal, obs, names, view, p0, transfer):
    """(residuals over their sigmas (P, 2), their Jacobian (2 P, n) sparse) by central differences of
    :class:`_Model`. A board pose's columns are differenced on its own view only (the same numbers
    as over all views, whose other rows difference to exactly 0)."""
    model = _Model(cal, obs)
    r0 = model.residuals(p0, transfer)
    rows_of = {i: np.repeat(view == i, 2) for i in range(len(obs.views))}
    cols, rows, vals = [], [], []
    for j, n in enumerate(names):
        h = _step(n, p0[n])
        hi, lo = dict(p0), dict(p0)
        hi[n] += h
        lo[n] -= h
        i = int(n.split("/")[1].split(".")[0]) if n.startswith("cam_board/") else None
        views = None if i is None else (i,)
        col = (model.residuals(hi, transfer, views) - model.residuals(lo, transfer, views)).ravel() / (2 * h)
        at = np.arange(2 * len(r0)) if i is None else np.flatnonzero(rows_of[i])
        nz = col != 0
        rows.append(at[nz])
        vals.append(col[nz])
        cols.append(np.full(int(nz.sum()), j))
    J = scipy.sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                shape=(2 * len(r0), len(names)))
    return r0, J


def _self_check(aj: AdjustmentJacobian, ba):
    std = np.sqrt(np.diag(aj.covariance()))
    worst = max((abs(std[k] / ba.std[n] - 1), n) for k, n in enumerate(aj.names) if "/" not in n and ba.std.get(n))
    if worst[0] > SELF_CHECK_RTOL:
        raise UncertaintyError(f"the rebuilt residual model does not reproduce the adjustment's covariance "
                               f"({worst[1]}: {100 * worst[0]:.1f} % off): not the model it solved")
