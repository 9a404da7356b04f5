"""Bundle adjustment of a camera + projector rig (or of one device) on board observations, casadi.

Building the problem and solving it are separate (COLMAP's way): ``BAConfig`` says what is
estimated and what is fixed, ``build_problem`` turns observations + a starting state into a
casadi function ``F(theta, p) -> (r, J)`` (residuals and their sparse Jacobian, float64), and
``solve`` runs Levenberg-Marquardt on it and returns a ``BAResult`` with the estimate, its
covariance and the residual statistics.

Model (per observed point k of board view i, device d; DESIGN.md conventions):

    X      = board point (x, y, z + warp(x, y))                     board frame, mm
    x_d    = R_d,i X + t_d,i                                        device frame, mm
    q      = K_d * distort(x_d / z_d, dist_d)                        pixels (with skew if estimated)
    r_k    = sqrt(w_k) * (q - q_obs) / sigma_k                       (2,) normalised residual

Poses. Joint mode: one board pose per view, ``rt_cam_board[i]``, shared by both devices, and one
rig transform ``rt_prj_cam``; the projector's pose of view i is ``rt_prj_cam o rt_cam_board[i]``.
Single-device mode: each device has its own board poses ``rt_dev_board[i]``. Gauge: the
reference frame is the camera frame (joint) or the device frame (single); it is fixed explicitly
by having no parameter for it, and the metric scale is fixed by the known board points.

Rotations are stored as a reference matrix R0 (a casadi parameter) times ``Exp(w)``; ``w`` is
the decision variable, reset to 0 after every accepted step (a manifold update), so the
linearisation and the covariance are in the local tangent space (radians) and never meet the
singularity of rotation vectors at 0 or pi.

Camera error transfer (joint mode, on by default where the observations carry ``dprj_dcam``).
A projector pixel is not measured independently of the camera: it is the decoded projector
coordinate read at the camera's detected feature, so a camera detection error ``e`` moves it by
``A e`` with ``A = d q_prj / d q_cam`` (the local gradient from the phase fit). Writing
``r_cam = q_cam(theta) - q_cam_obs`` (error ``-e``) and ``r_prj = q_prj(theta) - q_prj_obs``
(error ``-A e - eps``), the projector residual used is ``r_prj - A r_cam`` (error ``-eps``, the
phase error alone), whitened by the phase fit's sigma. This block-triangular change of the
residuals is exactly generalised least squares with the correlated covariance of the two
observations; without it the projector residuals repeat the camera's detection errors and the
covariance treats them as independent. Reported pixel residuals and RMS stay the plain
reprojection errors; ``stats["projector"]["rms_given_camera_px"]`` is the transferred one.

Board warp (optional, as mrcal's): ``z += c_x (1 - xn^2) + c_y (1 - yn^2)`` with ``xn, yn`` the
board coordinates scaled to [-1, 1] over the point extent; ``c`` in mm.

Conditioning: the solver works on ``z = (theta - theta_0) / s`` with ``s_j = 1 / |J_j|`` from
the starting Jacobian (Jacobi scaling), reported as the condition number before and after.

Robust loss: ``linear`` (plain least squares, default), ``huber`` or ``cauchy`` on the
normalised point residual norm, by iteratively reweighted least squares. Outlier rejection
(default on): points whose normalised residual exceeds ``outlier_threshold`` robust sigmas are
given weight 0 and listed in the result.

Covariance: ``sigma^2 (J^T J)^-1`` at the solution, ``sigma^2 = cost / (m - n)`` (the residual
variance), so standard deviations are scaled by how well the model fits.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .errors import BundleAdjustmentError

INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "skew")
DISTORTION_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4")
LOSSES = ("linear", "huber", "cauchy")
MODES = ("joint", "single")
SHORT = {"camera": "cam", "projector": "prj"}


@dataclass
class DeviceConfig:
    """What to estimate for one device.

    - n_distortion: OpenCV distortion terms (0, 4, 5, 8, 12).
    - estimate_skew: estimate K[0,1] (default: fixed at 0 so mrcal files can be written).
    - fixed: names held at their starting value (``fx fy cx cy skew k1 .. s4``, or
      ``"intrinsics"`` for all of them).
    - values: ``((name, value), ...)`` parameters held at a given value instead (e.g. the principal
      point at the image centre and k2 = p1 = p2 = 0, as another tool's flags fix them).
    """

    n_distortion: int = 5
    estimate_skew: bool = False
    fixed: tuple = ()
    values: tuple = ()

    def __post_init__(self):
        if self.n_distortion not in (0, 4, 5, 8, 12):
            raise BundleAdjustmentError(f"n_distortion: expected 0, 4, 5, 8 or 12, got {self.n_distortion!r}")
        known = set(INTRINSIC_NAMES) | set(DISTORTION_NAMES) | {"intrinsics"}
        bad = [f for f in self.fixed if f not in known]
        if bad:
            raise BundleAdjustmentError(f"fixed: unknown parameter(s) {bad}; known: {sorted(known)}")
        for item in self.values:
            if len(item) != 2 or item[0] not in known - {"intrinsics"}:
                raise BundleAdjustmentError(f"values: expected (name, value) pairs with a known name, got {item!r}")
            if not np.isfinite(float(item[1])):
                raise BundleAdjustmentError(f"values: {item[0]} must be finite, got {item[1]!r}")
            if item[0] in DISTORTION_NAMES[self.n_distortion:]:
                raise BundleAdjustmentError(f"values: {item[0]} is not part of a {self.n_distortion}-term model")

    def value(self, name: str, start: float) -> float:
        """The starting value of ``name``: the given one (``values``) or ``start``."""
        return float(dict(self.values).get(name, start))

    def is_fixed(self, name: str) -> bool:
        if "intrinsics" in self.fixed:
            return True
        if name == "skew" and not self.estimate_skew:
            return True
        return name in self.fixed or name in dict(self.values)


@dataclass
class BAConfig:
    """Problem and solver settings (defaults named and tested)."""

    mode: str = "joint"
    camera: DeviceConfig = field(default_factory=DeviceConfig)
    projector: DeviceConfig = field(default_factory=DeviceConfig)
    board_warp: bool = False
    loss: str = "linear"
    loss_scale: float = 3.0            # in normalised units (sigma of a point)
    outlier_threshold: float | None = 5.0   # robust sigmas; None: no rejection
    reweight_devices: bool = True      # two devices: weight each by its own residual RMS
    camera_error_transfer: bool = True  # joint: projector residual r_prj - A r_cam (module docstring)
    max_iterations: int = 300
    tolerance: float = 1e-15           # relative cost decrease that counts as converged
    progress: object = None            # callable(str) or None

    def __post_init__(self):
        if self.mode not in MODES:
            raise BundleAdjustmentError(f"mode: expected one of {MODES}, got {self.mode!r}")
        if self.loss not in LOSSES:
            raise BundleAdjustmentError(f"loss: expected one of {LOSSES}, got {self.loss!r}")
        if not self.loss_scale > 0:
            raise BundleAdjustmentError(f"loss_scale must be > 0, got {self.loss_scale!r}")

    def device(self, name: str) -> DeviceConfig:
        return self.camera if name == "camera" else self.projector


@dataclass
class RigState:
    """A full parameter state (starting point or estimate).

    - K: {device: (3,3)}, dist: {device: (n,)}.
    - poses: {name: (R (3,3), t (3,))}: ``cam_board/i`` and ``prj_cam`` (joint) or
      ``camera_board/i``, ``projector_board/i`` (single); each maps the second frame into the first.
    - warp: (2,) mm.
    """

    K: dict
    dist: dict
    poses: dict
    warp: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def copy(self) -> "RigState":
        return RigState({k: np.array(v) for k, v in self.K.items()},
                        {k: np.array(v) for k, v in self.dist.items()},
                        {k: (np.array(R), np.array(t)) for k, (R, t) in self.poses.items()},
                        np.array(self.warp))


def pose_chain(mode: str, device: str, view: int) -> list[str]:
    """Names of the poses composed (left to right) to map board view ``view`` into ``device``."""
    if mode == "single":
        return [f"{device}_board/{view}"]
    return [f"cam_board/{view}"] if device == "camera" else ["prj_cam", f"cam_board/{view}"]


# -- casadi model -----------------------------------------------------------------------------
def _exp_so3(ca, w):
    """Rotation matrix Exp(w) (casadi SX 3x3), smooth at w = 0."""
    th2 = ca.dot(w, w)
    th = ca.sqrt(ca.fmax(th2, 1e-300))
    small = th2 < 1e-8
    a = ca.if_else(small, 1 - th2 / 6 + th2 * th2 / 120, ca.sin(th) / th)
    b = ca.if_else(small, 0.5 - th2 / 24 + th2 * th2 / 720, (1 - ca.cos(th)) / th2)
    W = ca.skew(w)
    return ca.SX.eye(3) + a * W + b * (W @ W)


def _distort(ca, x, y, c):
    """OpenCV distortion on casadi row vectors; c = list of SX coefficients (0..12)."""
    n = len(c)
    if n == 0:
        return x, y
    c = list(c) + [0.0] * (12 - n)
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = c
    r2 = x * x + y * y
    r4 = r2 * r2
    r6 = r4 * r2
    radial = 1 + k1 * r2 + k2 * r4 + k3 * r6
    if n >= 8:
        radial = radial / (1 + k4 * r2 + k5 * r4 + k6 * r6)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    if n == 12:
        xd = xd + s1 * r2 + s2 * r4
        yd = yd + s3 * r2 + s4 * r4
    return xd, yd


@dataclass
class BAProblem:
    """A built problem: layout, starting state and the casadi function.

    - names (n,): parameter names; theta0 (n,): starting values (rotation increments 0).
    - free (n,) bool: which are estimated.
    - F: casadi Function (theta, p) -> (r (m,), J (m, n) sparse).
    - pose_names, pose_slices: where each pose's (w, t) sits in theta.
    - blocks: list of dicts (device, view, rows, points index) describing residual rows.
    - p_R0_slice, p_w_slice: where rotation references and point weights sit in p.
    """

    config: BAConfig
    obs: object
    names: list
    theta0: np.ndarray
    free: np.ndarray
    F: object
    pose_names: list
    pose_index: dict
    blocks: list
    R0: dict
    n_points: int
    point_sigma: np.ndarray
    point_device: np.ndarray
    point_view: np.ndarray
    point_id: np.ndarray
    build_seconds: float
    transfer_link: np.ndarray | None = None   # (P,) camera point index of each transferred projector point, -1
    transfer_A: np.ndarray | None = None      # (P, 2, 2) d q_prj / d q_cam of those points (0 elsewhere)

    def param_index(self, name: str) -> int:
        return self.names.index(name)

    def pack_p(self, R0: dict, sqrt_w: np.ndarray) -> np.ndarray:
        return np.concatenate([np.concatenate([R0[n].ravel(order="F") for n in self.pose_names]), sqrt_w])


def build_problem(obs, start: RigState, config: BAConfig) -> BAProblem:
    """Build the residual function of ``obs`` (``calib.observations.Observations``).

    ``start`` gives intrinsics and poses (see ``RigState``); the layout follows ``config``.
    """
    import casadi as ca

    t0 = time.perf_counter()
    devices = [d for d in ("camera", "projector") if obs.count(d) > 0]
    if config.mode == "joint" and devices != ["camera", "projector"]:
        raise BundleAdjustmentError(f"joint mode needs camera and projector observations; have {devices}")
    names, theta0, free = [], [], []

    def add(name, value, is_free):
        names.append(name)
        theta0.append(float(value))
        free.append(bool(is_free))
        return len(names) - 1

    intr, dist = {}, {}
    for d in devices:
        dc = config.device(d)
        K = start.K[d]
        vals = (K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1] if dc.estimate_skew else 0.0)
        intr[d] = [add(f"{d}.{n}", dc.value(n, v), not dc.is_fixed(n)) for n, v in zip(INTRINSIC_NAMES, vals)]
        d0 = np.zeros(dc.n_distortion)
        given = np.asarray(start.dist.get(d, np.zeros(0)), float)
        d0[:min(given.size, d0.size)] = given[:d0.size]
        dist[d] = [add(f"{d}.{n}", dc.value(n, v), not dc.is_fixed(n)) for n, v in zip(DISTORTION_NAMES, d0)]
    n_views = len(obs.views)
    pose_names = []
    if config.mode == "joint":
        pose_names = ["prj_cam"] + [f"cam_board/{i}" for i in range(n_views)]
    else:
        pose_names = [f"{d}_board/{i}" for d in devices for i in range(n_views) if obs.views[i].seen(d).any()]
    pose_index = {}
    for pn in pose_names:
        if pn not in start.poses:
            raise BundleAdjustmentError(f"starting state lacks pose {pn!r}")
        R, t = start.poses[pn]
        pose_index[pn] = [add(f"{pn}.w{j}", 0.0, True) for j in range(3)] + \
                         [add(f"{pn}.t{j}", t[j], True) for j in range(3)]
    warp_idx = []
    if config.board_warp:
        warp_idx = [add(f"board_warp.c{a}", start.warp[j], True) for j, a in enumerate("xy")]

    n = len(names)
    theta = ca.SX.sym("theta", n)
    R0_syms = {pn: ca.SX.sym(f"R0_{pn}", 3, 3) for pn in pose_names}
    # total observed points, for the weight parameters
    blocks, sig, pdev, pview, pid = [], [], [], [], []
    row = 0
    for i, v in enumerate(obs.views):
        for d in devices:
            m = v.seen(d)
            if not m.any():
                continue
            blocks.append({"device": d, "view": i, "points": np.flatnonzero(m),
                           "rows": np.arange(row, row + 2 * int(m.sum()))})
            row += 2 * int(m.sum())
            sig.append(v.sigma[d][m])
            pdev += [d] * int(m.sum())
            pview += [i] * int(m.sum())
            pid.append(v.ids[m])
    n_points = row // 2
    sqrt_w = ca.SX.sym("sqrt_w", n_points)

    pose_RT = {}
    for pn in pose_names:
        idx = pose_index[pn]
        w = ca.vertcat(*[theta[j] for j in idx[:3]])
        t = ca.vertcat(*[theta[j] for j in idx[3:]])
        pose_RT[pn] = (R0_syms[pn] @ _exp_so3(ca, w), t)
    # extent of board points, for the warp normalisation
    allX = np.concatenate([v.points_board for v in obs.views])
    half = np.maximum((allX[:, :2].max(0) - allX[:, :2].min(0)) / 2, 1e-9)
    mid = (allX[:, :2].max(0) + allX[:, :2].min(0)) / 2
    residuals = []
    kpt = 0
    transfer = config.mode == "joint" and config.camera_error_transfer
    transfer_link = np.full(n_points, -1, dtype=np.int64)
    transfer_A = np.zeros((n_points, 2, 2))
    cam_rows = {}   # view -> (points (Nc,), first point index, raw residual rows ru (1,Nc), rv (1,Nc))
    for b in blocks:
        d, i, pts = b["device"], b["view"], b["points"]
        v = obs.views[i]
        X = v.points_board[pts]
        q_obs = v.q[d][pts]
        s_pt = v.sigma[d][pts]
        Xs = ca.DM(X.T)
        if warp_idx:
            xn = (X[:, 0] - mid[0]) / half[0]
            yn = (X[:, 1] - mid[1]) / half[1]
            dz = theta[warp_idx[0]] * ca.DM(1 - xn ** 2).T + theta[warp_idx[1]] * ca.DM(1 - yn ** 2).T
            Xs = ca.vertcat(Xs[0, :], Xs[1, :], Xs[2, :] + dz)
        R, t = None, None
        for pn in reversed(pose_chain(config.mode, d, i)):  # compose right to left
            Rp, tp = pose_RT[pn]
            R, t = (Rp, tp) if R is None else (Rp @ R, Rp @ t + tp)
        P = R @ Xs + ca.repmat(t, 1, len(pts))
        x = P[0, :] / P[2, :]
        y = P[1, :] / P[2, :]
        fx, fy, cx, cy, s = (theta[j] for j in intr[d])
        xd, yd = _distort(ca, x, y, [theta[j] for j in dist[d]])
        u = fx * xd + s * yd + cx
        vv = fy * yd + cy
        ww = sqrt_w[kpt:kpt + len(pts)].T
        raw_u = u - ca.DM(q_obs[:, 0]).T
        raw_v = vv - ca.DM(q_obs[:, 1]).T
        if d == "camera":
            cam_rows[i] = (pts, kpt, raw_u, raw_v)
        elif transfer and i in cam_rows and v.dprj_dcam is not None:
            c_pts, c_k0, c_u, c_v = cam_rows[i]
            A = v.dprj_dcam[pts]
            cols = np.minimum(np.searchsorted(c_pts, pts), len(c_pts) - 1)   # c_pts is sorted
            linked = (c_pts[cols] == pts) & np.all(np.isfinite(A), axis=(1, 2))
            if linked.any():
                A = np.where(linked[:, None, None], A, 0.0)
                cols = np.where(linked, cols, 0)
                e_u, e_v = c_u[:, cols.tolist()], c_v[:, cols.tolist()]
                raw_u = raw_u - (ca.DM(A[:, 0, 0]).T * e_u + ca.DM(A[:, 0, 1]).T * e_v)
                raw_v = raw_v - (ca.DM(A[:, 1, 0]).T * e_u + ca.DM(A[:, 1, 1]).T * e_v)
                k_idx = kpt + np.flatnonzero(linked)
                transfer_link[k_idx] = c_k0 + cols[linked]
                transfer_A[k_idx] = A[linked]
        ru = ww * raw_u / ca.DM(s_pt).T
        rv = ww * raw_v / ca.DM(s_pt).T
        residuals.append(ca.reshape(ca.vertcat(ru, rv), -1, 1))
        kpt += len(pts)
    r = ca.vertcat(*residuals)
    p = ca.vertcat(*[ca.reshape(R0_syms[pn], -1, 1) for pn in pose_names], sqrt_w)
    J = ca.jacobian(r, theta)
    F = ca.Function("ba_residuals", [theta, p], [r, J])
    R0 = {pn: np.array(start.poses[pn][0], float) for pn in pose_names}
    return BAProblem(config, obs, names, np.array(theta0), np.array(free), F, pose_names, pose_index,
                     blocks, R0, n_points, np.concatenate(sig), np.array(pdev), np.array(pview),
                     np.concatenate(pid), time.perf_counter() - t0,
                     transfer_link if (transfer_link >= 0).any() else None,
                     transfer_A if (transfer_link >= 0).any() else None)
