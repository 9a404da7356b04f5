"""Gauss-Newton / Newton solver with Levenberg-Marquardt safeguards, device noise, robust
reweighting, outlier rejection and covariance for a BAProblem.

The problem (``calib.adjustment.problem.build_problem``) evaluates whitened residuals and their
block Jacobian; the normal equations are reduced on the global parameters (``calib.adjustment.normal``).

Iteration. Every iteration linearises once at the current state, with the point weights computed
*at that state*: device weights (two devices: each device's inlier points weighted by
``1 / s_d^2``, ``s_d^2`` the mean squared whitened residual per coordinate of that device) times
the robust-loss weights (IRLS, on the device-weighted residual norm) times the inlier mask. With
two devices and the linear loss the device noise is estimated jointly with the parameters
(``_Objective``: a profile likelihood whose Hessian adds one rank-one term per device). The step is
Gauss-Newton (``lam = 0``), or Newton's (the residuals' second-order term added,
``BAProblem.second_order``) once Gauss-Newton is seen to converge linearly near the optimum; a
quadratic line search scales it where the objective along it is not the model's;
Levenberg-Marquardt damping ``lam * diag(J^T J)`` is switched on only when no step lowers the
objective, and off again after good steps. The run stops when the step predicts a decrease below
``tolerance^2 * sigma^2`` (``sigma^2`` the residual variance): it would move the parameters by less
than ``tolerance`` standard deviations (Mahalanobis), so the state is a fixed point of the weights
and the minimiser of the cost they define. Points beyond ``outlier_threshold`` robust sigmas (per
device) are rejected as soon as the step is below ``OUTLIER_TOLERANCE`` sigmas, and the iteration
goes on from where it is.

Why this takes 5-18 linearisations where the previous solver took 54-113 (docs/calib.md, "Speed
and scale", has the measurements): (1) Gauss-Newton from the start, not damping ``lam = 1e-3``
divided by 5 per step: the smallest scaled eigenvalues of the paper's data are ~1e-7..1e-8 (the
projector's k2/k3 direction), so any damping above that turned the solve into a crawl (cost 27.55
-> 27.17 -> 27.10 -> ... over 28 steps); (2) the weights are updated at every step instead of in
outer rounds that each re-ran a full solve from a fresh damping (4 rounds of 25-28 steps), and the
device noise converges with the parameters instead of by fixed-point iteration (~25x per step);
(3) on real data even undamped Gauss-Newton converges only linearly (0.3-0.4 per step, alternating
directions: the residuals' curvature matters where J^T J is nearly singular; mrcal's dogleg shows
the same), which the line search and Newton's term remove; (4) convergence is judged on the
predicted step in units of the parameters' own uncertainty instead of a 1e-15 relative cost
decrease, which rounding noise rarely satisfies.

Covariance: ``sigma^2 (J^T J)^-1`` from the last Gauss-Newton factorisation, ``sigma^2 = cost /
(m - n)``. Parameters the data hardly determine are flagged (``BAResult.poorly_determined``; see
``poorly_determined``): three standard deviations beyond the value (distortion) or beyond a
fraction of the focal length / image size, or a correlation near 1 with another parameter of the
same device. A (numerically) singular problem is refused naming what the views do not determine.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from threadpoolctl import ThreadpoolController

from .normal import NormalEquations, SingularNormalEquations
from .problem import BAProblem, BundleAdjustmentError, RigState

CHI2_2DOF_MEDIAN = 2.0 * np.log(2.0)
CORRELATION_FLAG = 0.9999      # |correlation| between two device parameters that is flagged
FLAG_FRACTION = 0.05           # 3 sigma beyond this fraction of f (fx, fy, skew) or the image (cx, cy)
LAM_FIRST = 1e-6               # damping after a failed Gauss-Newton step (scaled: diag(J^T J) = 1)
LAM_MAX = 1e10
MAX_REJECTED_STEPS = 12        # consecutive failed steps: the cost cannot be lowered (rounding)
ROUNDING = 1e-14               # relative cost change below what a sum of squares resolves
STALL = 1e-10                  # a failed step predicting less (relative) is not retried with damping
LINE_SEARCH_MIN = 0.25         # line search step when the quadratic's minimum is this far from 1
LINE_SEARCH_RANGE = (0.05, 20.0)
OUTLIER_TOLERANCE = 1e-1       # outliers are looked for once the step is below this many sigmas
MAX_OUTLIER_ROUNDS = 10
NEWTON_SWITCH = 0.1            # |actual / predicted decrease - 1| of a Gauss-Newton step that
NEWTON_NEAR = 1e-2             # predicts less than this fraction of the cost: switch to Newton steps
NEWTON_RATE = 1e-2             # ... as when its predicted decrease falls by less than this per step


@dataclass
class BAResult:
    """Estimate, uncertainty and residual statistics of one adjustment.

    - state: RigState at the solution; names (n,), theta (n,) parameter vector (rotation entries
      are tangent increments, 0 at the solution).
    - std: {name: standard deviation} of every estimated parameter (rotations: rad, tangent).
    - cov: (G, G) covariance of the estimated global parameters (intrinsics, distortion, rig,
      warp), ``cov_names`` their names; ``free_names`` every estimated parameter (poses too).
    - sigma2: residual variance of the whitened, weighted residuals (scales the covariance).
    - device_sigma_px: {device: per-coordinate noise used to weight the device}.
    - residuals_px: (P, 2) pixel residuals of every observed point (predicted - observed);
      point_device, point_view, point_id: (P,) which point; inlier: (P,) bool.
    - stats: {"camera": {...}, "projector": {...}, "views": [...]} residual statistics (px).
    - rejected: list of {device, view, id, residual_px} outliers.
    - poorly_determined: list of {name, value, std, reasons} (see the module docstring).
    - iterations (linearisations), converged, cost, timings (s, and kernel evaluations),
      conditioning (condition numbers at the solution), backend (residual kernel).
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
    cov_names: list = field(default_factory=list)
    poorly_determined: list = field(default_factory=list)
    backend: str = ""


def _robust_weights(e, loss, c):
    if loss == "huber":
        return np.where(e <= c, 1.0, c / np.maximum(e, 1e-300))
    if loss == "cauchy":
        return 1.0 / (1.0 + (e / c) ** 2)
    return np.ones_like(e)


def _weights(problem: BAProblem, e, inlier, devices):
    """(device weights (P,), robust weights (P,)) at whitened point residual norms ``e``."""
    cfg = problem.config
    dev_w = np.ones(problem.n_points)
    if cfg.reweight_devices and len(devices) > 1:
        for d in devices:
            m = problem.point_device == d
            s2 = np.mean(e[m & inlier] ** 2) / 2.0 if (m & inlier).any() else 1.0
            dev_w[m] = 1.0 / max(s2, 1e-30)
    return dev_w, _robust_weights(e * np.sqrt(dev_w), cfg.loss, cfg.loss_scale)


def _reject_outliers(problem: BAProblem, e, inlier, devices, log) -> bool:
    """Mark points beyond ``outlier_threshold`` robust sigmas of their device; True if any."""
    cfg = problem.config
    changed = False
    for d in devices:
        m = problem.point_device == d
        sig = np.sqrt(np.median(e[m & inlier] ** 2) / CHI2_2DOF_MEDIAN)
        bad = m & inlier & (e > cfg.outlier_threshold * max(sig, 1e-12))
        if bad.any():
            inlier[bad] = False
            changed = True
            log.append(f"outliers: {int(bad.sum())} {d} point(s) beyond {cfg.outlier_threshold} "
                       f"robust sigma ({sig:.4g})")
    return changed


def _stats(res_px, mask):
    if not mask.any():
        return {"n": 0, "rms_px": None, "std_px": None, "max_px": None, "mean_px": None}
    rr = res_px[mask]
    norm = np.linalg.norm(rr, axis=1)
    return {"n": int(mask.sum()), "rms_px": float(np.sqrt(np.mean(rr ** 2))),
            "std_px": np.std(rr, axis=0, ddof=1).tolist() if len(rr) > 1 else [0.0, 0.0],
            "mean_px": rr.mean(axis=0).tolist(), "max_px": float(norm.max())}


def _stats_per_view(res_px, point_view, mask, n_views: int) -> list:
    """``_stats`` of the points in ``mask`` of each view (one pass: sums per view)."""
    v, rr = point_view[mask], res_px[mask]
    n = np.bincount(v, minlength=n_views)
    s1 = np.stack([np.bincount(v, rr[:, c], n_views) for c in (0, 1)], axis=1)
    s2 = np.stack([np.bincount(v, rr[:, c] ** 2, n_views) for c in (0, 1)], axis=1)
    mx = np.zeros(n_views)
    np.maximum.at(mx, v, np.sqrt(np.sum(rr ** 2, axis=1)))
    out = []
    for k in range(n_views):
        if n[k] == 0:
            out.append({"n": 0, "rms_px": None, "std_px": None, "max_px": None, "mean_px": None})
            continue
        mean = s1[k] / n[k]
        std = np.sqrt(np.maximum(s2[k] - n[k] * mean ** 2, 0.0) / (n[k] - 1)) if n[k] > 1 else np.zeros(2)
        out.append({"n": int(n[k]), "rms_px": float(np.sqrt(s2[k].sum() / (2 * n[k]))), "std_px": std.tolist(),
                    "mean_px": mean.tolist(), "max_px": float(mx[k])})
    return out


def poorly_determined(names, values, cov, sizes=None) -> list:
    """Device parameters the observations hardly determine (a finite estimate that should not be
    trusted or reported without comment).

    A parameter is flagged when three standard deviations exceed its scale: its own magnitude for
    distortion coefficients (the value is not distinguishable from 0), ``FLAG_FRACTION`` of the
    focal length for fx, fy and skew, ``FLAG_FRACTION`` of the image width / height for cx / cy
    (``sizes``: {device: (width, height)}); or when its correlation with another parameter of the
    same device exceeds ``CORRELATION_FLAG`` in magnitude. ``names`` (G,), ``values`` (G,),
    ``cov`` (G, G). Returns [{name, value, std, reasons}], each reason a phrase.
    """
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std, std)
    value = dict(zip(names, values))
    split = [n.split(".", 1) if n.split(".")[0] in ("camera", "projector") else (None, n) for n in names]
    out = []
    for j, (device, p) in enumerate(split):
        if device is None:
            continue
        reasons = []
        size = (sizes or {}).get(device)
        if p in ("fx", "fy", "skew"):
            scale, what = FLAG_FRACTION * abs(value.get(f"{device}.fx", values[j])), \
                f"{FLAG_FRACTION:.0%} of the focal length"
        elif p in ("cx", "cy") and size is not None:
            scale, what = FLAG_FRACTION * size[0 if p == "cx" else 1], \
                f"{FLAG_FRACTION:.0%} of the image {'width' if p == 'cx' else 'height'}"
        elif p in ("cx", "cy"):
            scale, what = np.inf, ""
        else:
            scale, what = abs(values[j]), "|value| (not distinguishable from 0)"
        if 3 * std[j] > scale:
            reasons.append(f"3 sigma > {what}")
        partners = [(abs(corr[j, k]), k) for k in range(len(names)) if k != j and split[k][0] == device]
        if partners:
            c, k = max(partners)
            if c > CORRELATION_FLAG:
                reasons.append(f"correlation {corr[j, k]:+.5f} with {split[k][1]}")
            elif reasons:
                reasons.append(f"largest correlation {corr[j, k]:+.3f}, with {split[k][1]}")
        if reasons and not (len(reasons) == 1 and reasons[0].startswith("largest")):
            out.append({"name": names[j], "value": float(values[j]), "std": float(std[j]), "reasons": reasons})
    return out


def _undetermined(problem: BAProblem, ne: NormalEquations) -> str:
    """Names of the parameters in the worst-determined direction of the normal matrix."""
    g, slot = ne.weakest_direction()
    if slot is not None:
        return f"the board pose {problem.pose_names[slot]}"
    big = np.flatnonzero(np.abs(g) > 0.25 * np.abs(g).max())
    return "the combination of " + ", ".join(problem.global_names[problem.global_free_index[k]] for k in big)


def _solve_or_none(ne: NormalEquations, lam: float, second_order=None, low_rank=None):
    """The step of ``ne`` (plus a second-order term, for Newton; minus the low-rank term of the
    device noise, see ``_Objective``) at damping ``lam``, or None where the matrix is not positive
    definite (with ``low_rank``: the step without it)."""
    eq = ne.plus_second_order(*second_order) if second_order is not None else ne
    try:
        return eq.solve(lam, low_rank)
    except SingularNormalEquations:
        return _solve_or_none(ne, lam, second_order) if low_rank is not None else None


class _Objective:
    """What a step must lower, relative to the current state (so that tiny changes are resolved).

    Fixed weights: the weighted sum of squares. With two devices weighted by their own noise
    (``reweight_devices``, linear loss) the weights are themselves estimates, ``w_d = m_d / S_d``
    (``m_d`` residual rows, ``S_d`` their sum of squares): the adjustment then maximises the
    likelihood with each device's variance profiled out, ``Phi = sum_d m_d log S_d``, whose
    gradient is the weighted one and whose Hessian is the weighted one minus
    ``sum_d (2 / m_d) g_d g_d^T`` (``g_d`` device d's share of ``J^T W r``): the rank-one terms
    ``low_rank`` gives ``NormalEquations.solve``. With them the weights converge with the
    parameters (quadratically) instead of by fixed-point iteration (linearly, ~25x per step).
    """

    def __init__(self, problem: BAProblem, ev, sw, inlier, devices, profile: bool):
        self.sw = sw
        self.cost = float(np.sum((ev.r * sw) ** 2))
        self.groups, self.low_rank = [], None
        if profile:
            masks = [problem.point_rows(((problem.point_device == d) & inlier).astype(float)) > 0 for d in devices]
            self.groups = [(m, 2.0 * np.count_nonzero(m) // 2, float(np.sum(ev.r[m] ** 2))) for m in masks]
            self.low_rank = [2.0 / m_d for _, m_d, _ in self.groups]

    @property
    def row_groups(self):
        return [m for m, _, _ in self.groups]

    def change(self, ev) -> float:
        """Objective at ``ev`` minus the current one (inf where ``ev`` is not valid)."""
        if not ev.valid:
            return np.inf
        if not self.groups:
            return float(np.sum((ev.r * self.sw) ** 2)) - self.cost
        return float(sum(m_d * np.log1p((np.sum(ev.r[m] ** 2) - S0) / S0) for m, m_d, S0 in self.groups))


def _try_step(problem: BAProblem, state, step, objective: _Objective):
    """Evaluate ``state + step`` (and, by a quadratic line search, a multiple of it); returns
    (state, evaluation, objective change) of the best point if it lowers the objective (else
    Nones), and the number of evaluations."""
    best, n_eval = (None, None, 0.0), 0
    alpha = 1.0
    for _ in range(2):
        trial = state.moved(problem, alpha * step.dg, alpha * step.dv)
        ev = problem.evaluate(trial)
        n_eval += 1
        c = objective.change(ev)
        if c < best[2]:
            best = (trial, ev, c)
        # a quadratic through the change 0 at alpha 0, its slope and the change at alpha 1: its
        # minimum, if well away from 1
        curvature = c - step.slope
        if n_eval > 1 or not (np.isfinite(c) and curvature > 0):
            break
        alpha = -step.slope / (2 * curvature)
        if not (abs(alpha - 1) > LINE_SEARCH_MIN and LINE_SEARCH_RANGE[0] < alpha < LINE_SEARCH_RANGE[1]):
            break
    return best[0], best[1], best[2], n_eval


def _outlier_round(problem: BAProblem, ev, inlier, devices, rounds: int, log) -> bool:
    """Reject outliers at the current residuals (if asked for and rounds remain); True if any."""
    cfg = problem.config
    if cfg.outlier_threshold is None or rounds >= MAX_OUTLIER_ROUNDS:
        return False
    if not _reject_outliers(problem, problem.point_norms(ev.r), inlier, devices, log):
        return False
    if cfg.progress:
        cfg.progress(f"  round {rounds + 1}: {int((~inlier).sum())} point(s) rejected so far")
    return True


_BLAS = []      # the process's one ThreadpoolController, made on the first solve


def solve(problem: BAProblem) -> BAResult:
    """Solve a built problem (see module docstring); raises BundleAdjustmentError on failure.

    The adjustment's linear algebra is many small matrices (6 x 6 pose blocks, the G x G reduced
    matrix with G <= 42); waking and synchronising BLAS threads for those costs far more than the
    arithmetic (inverting nine 6 x 6 blocks: 95 us of CPU with the default threads, 8 us with one,
    on the 2-core development machine), so the solve runs with one BLAS thread (threadpoolctl; the
    setting is process-wide for the duration of the solve).
    """
    if not _BLAS:
        _BLAS.append(ThreadpoolController())
    with _BLAS[0].limit(limits=1, user_api="blas"):
        return _solve(problem)


class _Run:
    """The state of one solve: parameters, evaluation, weights, inliers, damping, counters."""

    def __init__(self, problem: BAProblem):
        self.problem, self.cfg, self.log = problem, problem.config, []
        self.devices = sorted(set(problem.point_device))
        self.n_free = int(problem.free.sum())
        self.state = problem.start
        self.ev = problem.evaluate(self.state)
        if not self.ev.valid:
            raise BundleAdjustmentError("the starting point gives non-finite residuals or puts board points "
                                        "behind a device (a bad seed)")
        dead = [problem.global_names[j] for j, c in zip(problem.global_free_index, np.abs(self.ev.Jg).sum(axis=0))
                if c == 0]
        if dead:
            raise BundleAdjustmentError(f"parameters not constrained by any observation: {dead[:8]}")
        self.inlier = np.ones(problem.n_points, bool)
        self.profile = self.cfg.reweight_devices and len(self.devices) > 1 and self.cfg.loss == "linear"
        self.lam, self.iterations, self.evaluations, self.rounds = 0.0, 0, 1, 1
        self.newton, self.prev_gn, self.converged = False, None, False
        self.reweight()

    def reweight(self):
        self.dev_w, self.rob_w = _weights(self.problem, self.problem.point_norms(self.ev.r), self.inlier,
                                          self.devices)

    def outlier_round(self) -> bool:
        if not _outlier_round(self.problem, self.ev, self.inlier, self.devices, self.rounds, self.log):
            return False
        self.rounds += 1
        self.reweight()
        self.prev_gn = None
        return True

    def linearise(self):
        """Normal equations and the undamped model step at the current state and weights."""
        problem = self.problem
        weights = self.dev_w * self.rob_w * self.inlier
        sw = np.sqrt(problem.point_rows(weights))
        row_scale = (sw * problem.inv_sigma_rows)[:, None]
        objective = _Objective(problem, self.ev, sw, self.inlier, self.devices, self.profile)
        ne = NormalEquations(self.ev.Jg * row_scale, self.ev.Jv * row_scale, self.ev.r * sw, problem.n_slots,
                             objective.row_groups)
        self.iterations += 1
        gn = _solve_or_none(ne, 0.0, low_rank=objective.low_rank)
        if gn is not None and self.cfg.newton and not self.newton:
            # Gauss-Newton converging linearly near the optimum (its predicted decrease falling by
            # less than NEWTON_RATE a step): the residuals' curvature matters, add the 2nd order
            self.newton = self.prev_gn is not None and gn.predicted < NEWTON_NEAR * ne.cost and \
                gn.predicted > NEWTON_RATE * self.prev_gn
            self.prev_gn = gn.predicted
        newton = _solve_or_none(ne, 0.0, problem.second_order(self.state, self.ev, weights), objective.low_rank) \
            if self.newton else None
        return ne, objective, gn, newton

    def take_step(self, ne, objective, gn, newton, predicted: float) -> bool:
        """Try the model steps, then damped Gauss-Newton ones; move to the first that lowers the
        objective. False where none does."""
        steps = [("newton", newton)] if newton is not None else []
        steps += [("gauss-newton", gn if self.lam == 0.0 else _solve_or_none(ne, self.lam))]
        for _ in range(MAX_REJECTED_STEPS):
            for kind, step in steps:
                if step is None:
                    continue
                trial, ev, change, n_eval = _try_step(self.problem, self.state, step, objective)
                self.evaluations += n_eval
                if trial is not None:
                    self._accept(kind, step, trial, ev, change, ne.cost)
                    return True
            if self.lam > LAM_MAX or predicted <= STALL * ne.cost:
                return False               # (a step this small fails by rounding: damping cannot help)
            self.lam = LAM_FIRST if self.lam == 0.0 else 10 * self.lam
            steps = [("gauss-newton", _solve_or_none(ne, self.lam))]
        return False

    def _accept(self, kind, step, trial, ev, change, cost):
        self.state, self.ev = trial, ev
        if kind == "gauss-newton":
            rho = -change / max(step.predicted, 1e-300)
            if self.lam == 0.0 and abs(rho - 1) > NEWTON_SWITCH and step.predicted < NEWTON_NEAR * cost \
                    and self.cfg.newton:
                self.newton = True         # near the optimum the Gauss-Newton model misjudges the cost
            if self.lam > 0.0:
                self.prev_gn = None
            self.lam = 0.0 if self.lam <= LAM_FIRST else self.lam / 10
        self.reweight()
        if self.cfg.progress:
            self.cfg.progress(f"  iteration {self.iterations} ({kind}): objective change {change:.6g}")

    def iterate(self):
        """Linearise, judge convergence and outliers, step; until converged or out of iterations.
        Returns the last normal equations (their factorisation gives the covariance)."""
        cfg = self.cfg
        while True:
            ne, objective, gn, newton = self.linearise()
            dof = max(2 * int(self.inlier.sum()) - self.n_free, 1)
            model = newton or gn            # the undamped model judges convergence
            predicted = model.predicted if model is not None else np.inf
            small = predicted <= max(cfg.tolerance ** 2 * ne.cost / dof, ROUNDING * ne.cost)
            near = predicted <= OUTLIER_TOLERANCE ** 2 * ne.cost / dof
            if (near or small) and self.outlier_round():
                continue
            if small:
                self.converged = True
                if model is not None and model.predicted > 0:
                    # the last (tiny) step of the converged model: free precision, checked only
                    # against an increase beyond rounding
                    trial = self.state.moved(self.problem, model.dg, model.dv)
                    ev = self.problem.evaluate(trial)
                    self.evaluations += 1
                    if objective.change(ev) <= ROUNDING * ne.cost:
                        self.state, self.ev = trial, ev
                return ne
            if self.iterations >= cfg.max_iterations:
                self.log.append(f"stopped after {self.iterations} iterations without converging")
                return ne
            if not self.take_step(ne, objective, gn, newton, predicted):
                if gn is None:
                    raise BundleAdjustmentError("the normal matrix is singular: some parameters are not "
                                                "determined by the observations (degenerate views?)")
                self.log.append(f"no step lowers the cost further (rounding); stopped at cost {ne.cost:.12g}")
                if self.outlier_round():
                    continue
                self.converged = True
                return ne


def _covariance(problem: BAProblem, ne: NormalEquations, sigma2: float):
    """(covariance of the free globals, of each pose (S, 6, 6), conditioning), scaled by ``sigma2``;
    a (numerically) singular matrix is refused naming what the views do not determine."""
    refusal = (f"the views do not determine {{}} (degenerate geometry, or a model with more terms than the "
               "views constrain: fix them or use fewer)")
    try:
        cov_g, cov_v = ne.covariance()
        conditioning = ne.conditioning()
    except (SingularNormalEquations, np.linalg.LinAlgError):
        raise BundleAdjustmentError("the normal matrix is singular: " +
                                    refusal.format(_undetermined(problem, ne))) from None
    if conditioning["normal_matrix_rcond"] < 1e-15:
        raise BundleAdjustmentError(f"the normal matrix is numerically singular (rcond "
                                    f"{conditioning['normal_matrix_rcond']:.2e}): " +
                                    refusal.format(_undetermined(problem, ne)))
    return sigma2 * cov_g, sigma2 * cov_v, conditioning


def _statistics(problem: BAProblem, ev, inlier, devices):
    """(residual statistics per device and per view, rejected points) in pixels."""
    res_px = ev.r_px
    stats = {d: _stats(res_px, (problem.point_device == d) & inlier) for d in devices}
    if ev.r_transfer_px is not None:
        m = inlier[problem.transfer_prj]
        g = ev.r_transfer_px[m]
        stats["projector"]["rms_given_camera_px"] = float(np.sqrt(np.mean(g ** 2))) if m.any() else None
        stats["projector"]["n_transferred"] = int(len(problem.transfer_prj))
    n_views = len(problem.obs.views)
    stats["views"] = [{"view": i, "name": v.name} for i, v in enumerate(problem.obs.views)]
    for d in devices:
        m = problem.point_device == d
        rejected_per_view = np.bincount(problem.point_view[m & ~inlier], minlength=n_views)
        for entry, st, n_rej in zip(stats["views"], _stats_per_view(res_px, problem.point_view, m & inlier, n_views),
                                    rejected_per_view):
            entry[d] = dict(st, rejected=int(n_rej))
    rejected = [{"device": str(problem.point_device[k]), "view": int(problem.point_view[k]),
                 "id": int(problem.point_id[k]), "residual_px": float(np.linalg.norm(res_px[k]))}
                for k in np.flatnonzero(~inlier)]
    return stats, rejected


def _solve(problem: BAProblem) -> BAResult:
    t_start = time.perf_counter()
    run = _Run(problem)
    ne = run.iterate()
    inlier, log, P = run.inlier, run.log, problem.n_points
    cost = float(np.sum((run.ev.r * np.sqrt(problem.point_rows(run.dev_w * run.rob_w * inlier))) ** 2))
    log.append(f"{run.iterations} linearisations ({run.evaluations} evaluations, {run.rounds - 1} outlier "
               f"rejection round(s)), cost {cost:.12g}, converged={run.converged}")
    if (~inlier).sum() > 0.2 * P:
        raise BundleAdjustmentError(f"{int((~inlier).sum())} of {P} points rejected as outliers: the "
                                    "observations do not fit one model (wrong board, wrong pairing?)")
    m_rows = 2 * int(inlier.sum())
    dof = m_rows - run.n_free
    if dof <= 0:
        raise BundleAdjustmentError(f"{m_rows} residuals for {run.n_free} parameters: too few "
                                    "observations to estimate the model (add views or fix parameters)")
    sigma2 = cost / dof
    cov_g, cov_v, conditioning = _covariance(problem, ne, sigma2)
    cov_names = [problem.global_names[j] for j in problem.global_free_index]
    std = {n: float(np.sqrt(max(cov_g[k, k], 0.0))) for k, n in enumerate(cov_names)}
    pose_std = np.sqrt(np.maximum(np.einsum("sii->si", cov_v), 0.0))
    for s, pn in enumerate(problem.pose_names):
        for a, name in enumerate(("w0", "w1", "w2", "t0", "t1", "t2")):
            std[f"{pn}.{name}"] = float(pose_std[s, a])
    flagged = poorly_determined(cov_names, run.state.g[problem.global_free_index], cov_g,
                                getattr(problem.obs, "sizes", None))
    for f in flagged:
        log.append(f"poorly determined: {f['name']} = {f['value']:.6g} +- {f['std']:.3g} ({'; '.join(f['reasons'])})")
    stats, rejected = _statistics(problem, run.ev, inlier, run.devices)
    device_sigma = {d: float(np.sqrt(1.0 / run.dev_w[problem.point_device == d][0])) *
                    float(np.median(problem.point_sigma[problem.point_device == d])) for d in run.devices}
    free_names = [n for n, f in zip(problem.names, problem.free) if f]
    return BAResult(problem.rig_state(run.state), problem.names, problem.theta(run.state), std, cov_g, free_names,
                    sigma2, device_sigma, run.ev.r_px, problem.point_device, problem.point_view, problem.point_id,
                    inlier, stats, rejected, run.iterations, run.converged, cost,
                    {"build_s": problem.build_seconds, "solve_s": time.perf_counter() - t_start,
                     "evaluations": run.evaluations},
                    conditioning, problem.config.mode, log, cov_names, flagged, problem.backend)
