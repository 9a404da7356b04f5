"""Levenberg-Marquardt solver, robust reweighting, outlier rejection and covariance for a BAProblem.

The problem (``calib.bundle_adjustment.build_problem``) gives residuals and a sparse Jacobian;
this module only solves. Normal equations are formed from the sparse Jacobian and solved by
Cholesky (float64); the scaled parameters ``z = (theta - theta_0) / s`` make them well
conditioned. See ``calib.bundle_adjustment`` for the model and the conventions.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.sparse

from .bundle_adjustment import BAProblem, BundleAdjustmentError, RigState

CHI2_2DOF_MEDIAN = 2.0 * np.log(2.0)


def _exp_so3(w):
    th = float(np.linalg.norm(w))
    W = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    if th < 1e-8:
        return np.eye(3) + W + 0.5 * W @ W
    return np.eye(3) + np.sin(th) / th * W + (1 - np.cos(th)) / th ** 2 * W @ W


@dataclass
class BAResult:
    """Estimate, uncertainty and residual statistics of one adjustment.

    - state: RigState at the solution; names (n,), theta (n,) parameter vector (rotation entries
      are tangent increments, 0 at the solution).
    - std: {name: standard deviation} of every estimated parameter (rotations: rad, tangent).
    - cov: (n_free, n_free) covariance of the estimated parameters, ``free_names`` their names.
    - sigma2: residual variance of the normalised residuals (scales the covariance).
    - device_sigma_px: {device: per-coordinate noise used to weight the device}.
    - residuals_px: (P, 2) pixel residuals of every observed point (predicted - observed);
      point_device, point_view, point_id: (P,) which point; inlier: (P,) bool.
    - stats: {"camera": {...}, "projector": {...}, "views": [...]} residual statistics (px).
    - rejected: list of {device, view, id, residual_px} outliers.
    - iterations, converged, cost, timings (s), conditioning (condition numbers).
    """

    state: RigState
    names: list
    theta: np.ndarray
    std: dict
    cov: np.ndarray
    free_names: list
    sigma2: float
    device_sigma_px: dict
    residuals_px: np.ndarray
    point_device: np.ndarray
    point_view: np.ndarray
    point_id: np.ndarray
    inlier: np.ndarray
    stats: dict
    rejected: list
    iterations: int
    converged: bool
    cost: float
    timings: dict
    conditioning: dict
    mode: str
    log: list = field(default_factory=list)


class _Evaluator:
    def __init__(self, problem: BAProblem):
        self.problem = problem
        self.n = len(problem.names)
        self.calls = 0

    def __call__(self, theta, R0, sqrt_w, jacobian=True):
        self.calls += 1
        p = self.problem.pack_p(R0, sqrt_w)
        out = self.problem.F(theta, p)
        r = np.asarray(out[0]).ravel()
        if not jacobian:
            return r, None
        J = out[1]
        sp = J.sparsity()
        colind, rowind = sp.get_ccs()
        J = scipy.sparse.csc_matrix((np.asarray(J.nonzeros(), float), rowind, colind),
                                    shape=(J.size1(), J.size2()))
        return r, J


def _retract(problem: BAProblem, theta, R0):
    """Fold rotation increments into the references (R = R0 Exp(w)), set the increments to 0."""
    R0 = dict(R0)
    theta = theta.copy()
    for pn in problem.pose_names:
        idx = problem.pose_index[pn][:3]
        w = theta[idx]
        if np.any(w):
            R = R0[pn] @ _exp_so3(w)
            u, _, vt = np.linalg.svd(R)  # keep it exactly orthonormal
            R0[pn] = u @ vt
            theta[idx] = 0.0
    return theta, R0


def _lm(ev: _Evaluator, theta, R0, sqrt_w, free, scale, cfg, log):
    """Levenberg-Marquardt on the scaled free parameters; returns theta, R0, iterations, converged."""
    problem = ev.problem
    r, J = ev(theta, R0, sqrt_w)
    cost = float(r @ r)
    if not np.isfinite(cost):
        raise BundleAdjustmentError("the starting point gives non-finite residuals (a point behind a "
                                    "device or a bad seed)")
    lam = 1e-3
    converged = False
    it = 0
    for it in range(1, cfg.max_iterations + 1):
        Js = J[:, free] @ scipy.sparse.diags(scale)
        g = Js.T @ r
        A = (Js.T @ Js).toarray()
        diag = np.maximum(np.diag(A), 1e-12)
        accepted = False
        while lam < 1e16:
            try:
                c = scipy.linalg.cho_factor(A + lam * np.diag(diag))
                dz = -scipy.linalg.cho_solve(c, g)
            except (np.linalg.LinAlgError, ValueError):
                lam *= 10
                continue
            trial = theta.copy()
            trial[free] += scale * dz
            r_new, _ = ev(trial, R0, sqrt_w, jacobian=False)
            cost_new = float(r_new @ r_new)
            if np.isfinite(cost_new) and cost_new <= cost:
                accepted = True
                break
            lam *= 4
        if not accepted:
            converged = True  # no descent possible at any damping: at a minimum (to rounding)
            break
        decrease = cost - cost_new
        theta, R0 = _retract(problem, trial, R0)
        r, J = ev(theta, R0, sqrt_w)
        cost = float(r @ r)
        lam = max(lam / 5, 1e-12)
        step = float(np.max(np.abs(dz)))
        if cfg.progress and (it % 10 == 0 or it == 1):
            cfg.progress(f"  LM iteration {it}: cost {cost:.10g}, step {step:.2e}")
        if decrease <= cfg.tolerance * max(cost, 1e-300) and step < 1e-6:
            converged = True
            break
        if step < 1e-12:
            converged = True
            break
    log.append(f"LM: {it} iterations, cost {cost:.12g}, converged={converged}")
    return theta, R0, it, converged


def _point_norms(r):
    return np.sqrt(r[0::2] ** 2 + r[1::2] ** 2)


def _robust_weights(e, loss, c):
    if loss == "huber":
        return np.where(e <= c, 1.0, c / np.maximum(e, 1e-300))
    if loss == "cauchy":
        return 1.0 / (1.0 + (e / c) ** 2)
    return np.ones_like(e)


def _stats(res_px, mask):
    if not mask.any():
        return {"n": 0, "rms_px": None, "std_px": None, "max_px": None, "mean_px": None}
    rr = res_px[mask]
    norm = np.linalg.norm(rr, axis=1)
    return {"n": int(mask.sum()), "rms_px": float(np.sqrt(np.mean(rr ** 2))),
            "std_px": np.std(rr, axis=0, ddof=1).tolist() if len(rr) > 1 else [0.0, 0.0],
            "mean_px": rr.mean(axis=0).tolist(), "max_px": float(norm.max())}


def solve(problem: BAProblem) -> BAResult:
    """Solve a built problem (see module docstring); raises BundleAdjustmentError on failure."""
    cfg = problem.config
    t_start = time.perf_counter()
    ev = _Evaluator(problem)
    log = []
    theta = problem.theta0.copy()
    R0 = dict(problem.R0)
    free = problem.free.copy()
    P = problem.n_points
    inlier = np.ones(P, bool)
    dev_w = np.ones(P)
    robust_w = np.ones(P)

    r, J = ev(theta, R0, np.ones(P))
    col_norm = np.sqrt(np.asarray(J[:, free].multiply(J[:, free]).sum(axis=0)).ravel())
    dead = [problem.names[j] for j, cn in zip(np.flatnonzero(free), col_norm) if cn == 0]
    if dead:
        raise BundleAdjustmentError(f"parameters not constrained by any observation: {dead[:8]}")
    scale = 1.0 / col_norm
    Jf = J[:, free].toarray() if free.sum() < 3000 else None
    conditioning = {}
    if Jf is not None:
        conditioning["jacobian_unscaled"] = float(np.linalg.cond(Jf))
        conditioning["jacobian_scaled"] = float(np.linalg.cond(Jf * scale))
    devices = sorted(set(problem.point_device))
    iterations = 0
    converged = False
    rounds = 0
    while True:
        rounds += 1
        # IRLS loop at a fixed inlier set
        for irls in range(20):
            sqrt_w = np.sqrt(dev_w * robust_w) * inlier
            theta, R0, it, converged = _lm(ev, theta, R0, sqrt_w, free, scale, cfg, log)
            iterations += it
            if cfg.loss == "linear":
                break
            r_unit, _ = ev(theta, R0, np.sqrt(dev_w), jacobian=False)
            e = _point_norms(r_unit)
            new_w = _robust_weights(e, cfg.loss, cfg.loss_scale)
            if np.max(np.abs(new_w - robust_w)) < 1e-6:
                break
            robust_w = new_w
        r_plain, _ = ev(theta, R0, np.ones(P), jacobian=False)
        e_plain = _point_norms(r_plain)
        changed = False
        # device weights from the inlier residual RMS of each device (each device its own noise)
        if cfg.reweight_devices and len(devices) > 1:
            new_dev_w = np.ones(P)
            for d in devices:
                m = (problem.point_device == d) & inlier
                s2 = np.mean(e_plain[m] ** 2) / 2.0
                new_dev_w[problem.point_device == d] = 1.0 / max(s2, 1e-30)
            if np.max(np.abs(new_dev_w / dev_w - 1)) > 1e-3:
                dev_w = new_dev_w
                changed = True
        if cfg.outlier_threshold is not None:
            for d in devices:
                m = problem.point_device == d
                sig = np.sqrt(np.median(e_plain[m & inlier] ** 2) / CHI2_2DOF_MEDIAN)
                bad = m & inlier & (e_plain > cfg.outlier_threshold * max(sig, 1e-12))
                if bad.any():
                    inlier[bad] = False
                    changed = True
                    log.append(f"outliers: {int(bad.sum())} {d} point(s) beyond {cfg.outlier_threshold} "
                               f"robust sigma ({sig:.4g})")
            if cfg.progress and changed:
                cfg.progress(f"  round {rounds}: {int((~inlier).sum())} point(s) rejected so far")
        if not changed or rounds >= 10:
            break
    if (~inlier).sum() > 0.2 * P:
        raise BundleAdjustmentError(f"{int((~inlier).sum())} of {P} points rejected as outliers: the "
                                    "observations do not fit one model (wrong board, wrong pairing?)")
    # final Jacobian, covariance
    sqrt_w = np.sqrt(dev_w * robust_w) * inlier
    r, J = ev(theta, R0, sqrt_w)
    Js = (J[:, free] @ scipy.sparse.diags(scale)).toarray()
    m_rows = 2 * int(inlier.sum())
    dof = m_rows - int(free.sum())
    if dof <= 0:
        raise BundleAdjustmentError(f"{m_rows} residuals for {int(free.sum())} parameters: too few "
                                    "observations to estimate the model (add views or fix parameters)")
    sigma2 = float(r @ r) / dof
    A = Js.T @ Js
    try:
        Ainv = scipy.linalg.inv(A)
    except (np.linalg.LinAlgError, ValueError):
        raise BundleAdjustmentError("the normal matrix is singular: some parameters are not determined "
                                    "by the observations (degenerate views?)") from None
    rcond = 1.0 / np.linalg.cond(A)
    conditioning["normal_matrix_rcond"] = float(rcond)
    if rcond < 1e-15:
        raise BundleAdjustmentError(f"the normal matrix is numerically singular (rcond {rcond:.2e}): the "
                                    "views do not determine every parameter (degenerate geometry?)")
    cov = sigma2 * (scale[:, None] * Ainv * scale[None, :])
    free_names = [problem.names[j] for j in np.flatnonzero(free)]
    std = {n: float(np.sqrt(max(cov[k, k], 0.0))) for k, n in enumerate(free_names)}

    # pixel residuals of every point (unweighted)
    r_plain, _ = ev(theta, R0, np.ones(P), jacobian=False)
    res_px = np.stack([r_plain[0::2], r_plain[1::2]], axis=1) * problem.point_sigma[:, None]
    res_given_camera = None
    if problem.transfer_link is not None:
        # projector rows hold r_prj - A r_cam: add the camera part back for the plain reprojection error
        linked = problem.transfer_link >= 0
        res_given_camera = res_px[linked].copy()
        res_px[linked] += np.einsum("kij,kj->ki", problem.transfer_A[linked], res_px[problem.transfer_link[linked]])
    stats = {d: _stats(res_px, (problem.point_device == d) & inlier) for d in devices}
    if res_given_camera is not None:
        m = inlier[linked]
        stats["projector"]["rms_given_camera_px"] = (float(np.sqrt(np.mean(res_given_camera[m] ** 2)))
                                                     if m.any() else None)
        stats["projector"]["n_transferred"] = int(linked.sum())
    stats["views"] = []
    for i, v in enumerate(problem.obs.views):
        entry = {"view": i, "name": v.name}
        for d in devices:
            m = (problem.point_view == i) & (problem.point_device == d)
            entry[d] = _stats(res_px, m & inlier)
            entry[d]["rejected"] = int((m & ~inlier).sum())
        stats["views"].append(entry)
    rejected = [{"device": str(problem.point_device[k]), "view": int(problem.point_view[k]),
                 "id": int(problem.point_id[k]), "residual_px": float(np.linalg.norm(res_px[k]))}
                for k in np.flatnonzero(~inlier)]
    device_sigma = {d: float(np.sqrt(1.0 / dev_w[problem.point_device == d][0])) *
                    float(np.median(problem.point_sigma[problem.point_device == d])) for d in devices}
    state = _state_from_theta(problem, theta, R0)
    t_solve = time.perf_counter() - t_start
    return BAResult(state, list(problem.names), theta, std, cov, free_names, sigma2, device_sigma, res_px,
                    problem.point_device, problem.point_view, problem.point_id, inlier, stats, rejected,
                    iterations, converged, float(r @ r),
                    {"build_s": problem.build_seconds, "solve_s": t_solve, "evaluations": ev.calls},
                    conditioning, cfg.mode, log)


def _state_from_theta(problem: BAProblem, theta, R0) -> RigState:
    names = problem.names
    K, dist = {}, {}
    for d in ("camera", "projector"):
        if f"{d}.fx" not in names:
            continue
        g = lambda n: float(theta[names.index(f"{d}.{n}")])  # noqa: E731
        K[d] = np.array([[g("fx"), g("skew"), g("cx")], [0, g("fy"), g("cy")], [0, 0, 1.0]])
        dist[d] = np.array([theta[j] for j, n in enumerate(names)
                            if n.startswith(f"{d}.") and n.split(".")[1] not in
                            ("fx", "fy", "cx", "cy", "skew")])
    poses = {}
    for pn in problem.pose_names:
        idx = problem.pose_index[pn]
        poses[pn] = (R0[pn] @ _exp_so3(theta[idx[:3]]), theta[idx[3:]].copy())
    warp = np.array([theta[names.index(f"board_warp.c{a}")] for a in "xy"]) if \
        "board_warp.cx" in names else np.zeros(2)
    return RigState(K, dist, poses, warp)
