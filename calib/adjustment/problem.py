"""Bundle adjustment of a camera + projector rig (or of one device) on board observations.

Building the problem and solving it are separate (COLMAP's way): ``BAConfig`` says what is
estimated and what is fixed, ``build_problem`` lays the observations out (parameters, pose blocks,
points grouped by residual kernel) and ``BAProblem.evaluate`` gives, for a parameter state, the
whitened residuals and their Jacobian split into the global block (intrinsics, distortion, rig,
board warp) and one 6-column block per board pose; ``calib.adjustment.solver.solve`` runs the adjustment.

Model (per observed point k of board view i, device d; DESIGN.md conventions):

    X      = board point (x, y, z + warp(x, y))                     board frame, mm
    x_d    = R_d,i X + t_d,i                                        device frame, mm
    q      = K_d * distort(x_d / z_d, dist_d)                        pixels (with skew if estimated)
    r_k    = (q - q_obs) / sigma_k                                   (2,) whitened residual

The prediction ``q`` and its Jacobian blocks come from one compiled casadi function per model
structure (``calib.adjustment.kernel``: distortion terms x pose-chain length), evaluated over all points.

Poses. Joint mode: one board pose per view, ``rt_cam_board[i]``, shared by both devices, and one
rig transform ``rt_prj_cam``; the projector's pose of view i is ``rt_prj_cam o rt_cam_board[i]``.
Single-device mode: each device has its own board poses ``rt_dev_board[i]``. Gauge: the
reference frame is the camera frame (joint) or the device frame (single); it is fixed explicitly
by having no parameter for it, and the metric scale is fixed by the known board points.

Rotations are stored as matrices; the parameters are increments ``w`` on the right
(``R Exp(w)``), folded into the matrix after every accepted step (a manifold update), so the
linearisation and the covariance are in the local tangent space (radians) and never meet the
singularity of rotation vectors at 0 or pi.

Block structure: every residual depends on the global parameters and on exactly one pose block
(joint: ``cam_board/i``; single: ``camera_board/i`` or ``projector_board/i``). The residual rows
are laid out padded per pose block, ``(S, 2 * P_max)`` for S blocks of at most ``P_max`` points, so
the normal equations are formed by batched products and reduced on the global block (Schur
complement, ``calib.adjustment.normal``): one iteration costs time and memory linear in the views.

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

Robust loss: ``linear`` (plain least squares, default), ``huber`` or ``cauchy`` on the
whitened point residual norm, by iteratively reweighted least squares. Outlier rejection
(default on): points whose whitened residual exceeds ``outlier_threshold`` robust sigmas are
given weight 0 and listed in the result. Covariance: ``sigma^2 (J^T J)^-1`` at the solution,
``sigma^2 = cost / (m - n)`` (the residual variance). The solver's docstring says how these
weights are updated within one run of Gauss-Newton iterations.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..errors import BundleAdjustmentError

INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "skew")
DISTORTION_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4")
LOSSES = ("linear", "huber", "cauchy")
MODES = ("joint", "single")


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
    max_iterations: int = 100
    tolerance: float = 1e-6            # converged: Gauss-Newton step below this many sigmas (Mahalanobis)
    backend: str = "auto"              # residual kernel: "auto", "compiled", "vm" (calib.adjustment.kernel)
    newton: bool = True                # add the residuals' second-order term where Gauss-Newton crawls
    progress: object = None            # callable(str) or None

    def __post_init__(self):
        if self.mode not in MODES:
            raise BundleAdjustmentError(f"mode: expected one of {MODES}, got {self.mode!r}")
        if self.loss not in LOSSES:
            raise BundleAdjustmentError(f"loss: expected one of {LOSSES}, got {self.loss!r}")
        if not self.loss_scale > 0:
            raise BundleAdjustmentError(f"loss_scale must be > 0, got {self.loss_scale!r}")
        if self.backend not in ("auto", "compiled", "vm"):
            raise BundleAdjustmentError(f"backend: expected 'auto', 'compiled' or 'vm', got {self.backend!r}")
        if not (self.tolerance > 0 and self.max_iterations >= 1):
            raise BundleAdjustmentError(f"tolerance must be > 0 and max_iterations >= 1, got "
                                        f"{self.tolerance!r}, {self.max_iterations!r}")

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


# -- parameter state --------------------------------------------------------------------------
def exp_so3(w) -> np.ndarray:
    """Rotation matrices Exp(w) (..., 3, 3) of rotation vectors w (..., 3), radians (Rodrigues)."""
    w = np.asarray(w, dtype=np.float64)
    th2 = np.sum(w * w, axis=-1)[..., None, None]
    W = np.zeros(w.shape[:-1] + (3, 3))
    W[..., 0, 1], W[..., 0, 2], W[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    W[..., 1, 0], W[..., 2, 0], W[..., 2, 1] = w[..., 2], -w[..., 1], w[..., 0]
    small = th2 < 1e-8
    th = np.sqrt(np.where(small, 1.0, th2))
    a = np.where(small, 1 - th2 / 6 + th2 * th2 / 120, np.sin(th) / th)
    b = np.where(small, 0.5 - th2 / 24 + th2 * th2 / 720, (1 - np.cos(th)) / np.where(small, 1.0, th2))
    return np.eye(3) + a * W + b * (W @ W)


@dataclass
class ParamState:
    """A point of the adjustment: global values and pose blocks.

    - g (G,): global parameters (``BAProblem.global_names``); rig rotation entries are increments,
      0 between steps.
    - R_rig (3,3): ``R_prj_cam`` (joint mode), else None.
    - R (S,3,3), t (S,3): pose blocks (``BAProblem.pose_names``), board -> device (or camera), mm.
    """

    g: np.ndarray
    R_rig: np.ndarray | None
    R: np.ndarray
    t: np.ndarray

    def moved(self, problem: "BAProblem", dg_free: np.ndarray, dv: np.ndarray) -> "ParamState":
        """The state after a step: ``dg_free`` (G_free,) on the free globals, ``dv`` (S, 6) on
        the poses (rotation increment, translation); rotation increments folded into R."""
        g = self.g.copy()
        g[problem.global_free_index] += dg_free
        R_rig = self.R_rig
        if problem.rig_index is not None:
            w = problem.rig_index[:3]
            R_rig = R_rig @ exp_so3(g[w])
            g[w] = 0.0
        return ParamState(g, R_rig, self.R @ exp_so3(dv[:, :3]), self.t + dv[:, 3:])


@dataclass
class _PointGroup:
    """The points of one device evaluated by one kernel (arrays in the group's point order)."""

    device: str
    kernel: object
    points: np.ndarray        # (N,) global point indices
    slot: np.ndarray          # (N,) pose block
    pad: np.ndarray           # (N,) padded position, slot * P_max + position in the block
    X: np.ndarray             # (N, 3) board points, mm
    warp_basis: np.ndarray    # (N, 2)
    q_obs: np.ndarray         # (N, 2) px
    intr_index: np.ndarray    # (5 + n,) global index of each kernel intrinsic
    jmap: np.ndarray          # (L,) local variable -> free global column (>= 0), pose column (-2 - k), -1
    hessian_kernel: object = None   # built on first use (Newton steps)

    @property
    def local_src(self) -> np.ndarray:
        """Local variables (``KernelSpec.local_blocks``) that are free globals."""
        return np.flatnonzero(self.jmap >= 0)

    @property
    def local_dst(self) -> np.ndarray:
        """Their columns in the free global block."""
        return self.jmap[self.jmap >= 0]


@dataclass
class Evaluation:
    """Residuals and Jacobian at one state (``BAProblem.evaluate``).

    - valid: every point in front of its device(s) and every number finite.
    - r_px (P, 2): plain reprojection residuals, predicted - observed, px (point order).
    - r (S * P_max * 2,): whitened residuals with the camera error transfer, padded rows
      (unit point weights: the solver multiplies by its weights).
    - Jg (rows, G_free), Jv (rows, 6): Jacobian of the residuals *in pixels* (``r`` before
      whitening: multiply the rows by ``BAProblem.inv_sigma_rows``) w.r.t. the free globals and
      the pose block of each row (None when not asked for).
    - r_transfer_px (T, 2): projector residuals given the camera's (``r_prj - A r_cam``), px.
    """

    valid: bool
    r_px: np.ndarray
    r: np.ndarray
    Jg: np.ndarray | None
    Jv: np.ndarray | None
    r_transfer_px: np.ndarray | None


@dataclass
class BAProblem:
    """A built problem: parameter layout, starting state and the point groups.

    - global_names (G,), global_free (G,) bool; pose_names (S,) pose blocks.
    - names (n,), free (n,): every parameter (globals, then 6 per pose block ``NAME.w0..t2``).
    - start: ParamState; P_max: points of the largest pose block.
    - point_device, point_view, point_id, point_sigma (P,): which point, its sigma (px).
    - point_pad (P,): padded position of each point (rows ``2 pad`` and ``2 pad + 1``).
    - rig_index (6,), warp_index (2,): global indices of ``prj_cam.w0..t2`` and the warp, or None.
    - transfer_prj, transfer_cam (T,): global indices of transferred projector points and their
      camera points; transfer_A (T, 2, 2).
    """

    config: BAConfig
    obs: object
    global_names: list
    global_free: np.ndarray
    pose_names: list
    start: ParamState
    groups: list
    P_max: int
    n_points: int
    point_sigma: np.ndarray
    point_device: np.ndarray
    point_view: np.ndarray
    point_id: np.ndarray
    point_pad: np.ndarray
    rig_index: np.ndarray | None
    warp_index: np.ndarray | None
    build_seconds: float
    backend: str
    transfer_prj: np.ndarray | None = None
    transfer_cam: np.ndarray | None = None
    transfer_A: np.ndarray | None = None

    @cached_property
    def global_free_index(self) -> np.ndarray:
        return np.flatnonzero(self.global_free)

    @property
    def n_slots(self) -> int:
        return len(self.pose_names)

    @cached_property
    def names(self) -> list:
        return list(self.global_names) + [f"{pn}.{a}" for pn in self.pose_names for a in POSE_PARAMS]

    @cached_property
    def free(self) -> np.ndarray:
        return np.r_[self.global_free, np.ones(6 * self.n_slots, bool)]

    @property
    def n_rows(self) -> int:
        return 2 * self.n_slots * self.P_max

    @cached_property
    def inv_sigma_rows(self) -> np.ndarray:
        """(rows,) 1 / sigma of each residual row (0 on padding)."""
        return self.point_rows(1.0 / self.point_sigma)

    def point_rows(self, values_per_point: np.ndarray) -> np.ndarray:
        """Per-point values (P,) spread onto the padded residual rows (rows,), 0 on padding."""
        out = np.zeros(self.n_slots * self.P_max)
        out[self.point_pad] = values_per_point
        return np.repeat(out, 2)

    def point_norms(self, r_rows: np.ndarray) -> np.ndarray:
        """(P,) norm of each point's 2 residual rows."""
        r2 = r_rows.reshape(-1, 2)[self.point_pad]
        return np.sqrt(np.sum(r2 * r2, axis=1))

    def evaluate(self, state: ParamState, jacobian: bool = True) -> Evaluation:
        """Residuals (and Jacobian) at ``state``; see ``Evaluation``."""
        Gf = int(self.global_free.sum())
        n_pad = self.n_slots * self.P_max
        r = np.zeros((n_pad, 2))
        Jg = np.zeros((n_pad, 2, Gf)) if jacobian else None
        Jv = np.zeros((n_pad, 2, 6)) if jacobian else None
        valid = True
        for grp in self.groups:
            # the compiled kernel writes its points' rows straight into the padded arrays
            z = np.empty(len(grp.points))
            grp.kernel.assemble(self._kernel_inputs(grp, state), grp.pad, grp.q_obs, grp.jmap, r, z, Jg, Jv)
            valid = valid and bool(np.all(z > 0))
        r_px = r[self.point_pad]
        valid = valid and bool(np.all(np.isfinite(r_px)))
        r_transfer = None
        if self.transfer_prj is not None:
            pp, pc = self.point_pad[self.transfer_prj], self.point_pad[self.transfer_cam]
            A = self.transfer_A
            r[pp] -= np.einsum("kij,kj->ki", A, r[pc])
            r_transfer = r[pp]
            if jacobian:
                Jg[pp] -= A @ Jg[pc]
                Jv[pp] -= A @ Jv[pc]
        return Evaluation(valid, r_px, r.ravel() * self.inv_sigma_rows,
                          Jg.reshape(-1, Gf) if jacobian else None, Jv.reshape(-1, 6) if jacobian else None,
                          r_transfer)

    def _kernel_inputs(self, grp: _PointGroup, state: ParamState) -> list:
        inputs = [state.g[grp.intr_index], state.R[grp.slot].reshape(-1, 9), state.t[grp.slot]]
        if grp.kernel.spec.chain == 2:
            inputs += [state.R_rig.ravel(), state.g[self.rig_index[3:]]]
        warp = state.g[self.warp_index] if self.warp_index is not None else np.zeros(2)
        return inputs + [grp.X, grp.warp_basis, warp]

    def second_order(self, state: ParamState, ev: Evaluation, weights: np.ndarray):
        """The residuals' second-order term ``sum_i r_i d2r_i`` of the weighted cost at ``state``
        (``ev`` its evaluation, ``weights`` (P,) the point weights), in the blocks of
        ``calib.adjustment.normal.NormalEquations.plus_second_order``: (G_free, G_free), (S, G_free, 6),
        (S, 6, 6). The residuals are linear in the predicted pixels q (the camera error transfer
        included), so the term is ``sum_k mu_k . d2q_k`` with ``mu_k`` the cost's derivative with
        respect to point k's prediction (halved)."""
        from .kernel import KernelSpec, point_kernel

        S, Gf = self.n_slots, int(self.global_free.sum())
        r_pts = ev.r.reshape(-1, 2)[self.point_pad]
        mu = r_pts * (weights / self.point_sigma)[:, None]           # d(cost / 2) / dq, px^-1
        if self.transfer_prj is not None:
            np.add.at(mu, self.transfer_cam, -np.einsum("kji,kj->ki", self.transfer_A, mu[self.transfer_prj]))
        U2, W2, V2 = np.zeros((Gf, Gf)), np.zeros((S, Gf, 6)), np.zeros((S, 6, 6))
        for grp in self.groups:
            spec = grp.kernel.spec
            if grp.hessian_kernel is None:
                grp.hessian_kernel = point_kernel(KernelSpec(spec.n_distortion, spec.chain, True),
                                                  grp.kernel.backend)
            L = spec.n_local
            H = grp.hessian_kernel.evaluate(self._kernel_inputs(grp, state) + [mu[grp.points]],
                                            rows=grp.slot, n_rows=S, accumulate=True).reshape(S, L, L)
            p = slice(*spec.local_blocks["pose1"])
            src, dst = grp.local_src, grp.local_dst
            U2[np.ix_(dst, dst)] += H[:, src][:, :, src].sum(axis=0)
            W2[:, dst, :] += H[:, src, p]
            V2 += H[:, p, p]
        return U2, W2, V2

    def rig_state(self, state: ParamState) -> RigState:
        """The RigState (K, distortion, named poses, warp) of a parameter state."""
        names = self.global_names
        K, dist = {}, {}
        for d in ("camera", "projector"):
            if f"{d}.fx" not in names:
                continue
            g = {n.split(".", 1)[1]: state.g[k] for k, n in enumerate(names) if n.startswith(f"{d}.")}
            K[d] = np.array([[g["fx"], g["skew"], g["cx"]], [0, g["fy"], g["cy"]], [0, 0, 1.0]])
            dist[d] = np.array([g[n] for n in DISTORTION_NAMES if n in g])
        poses = {pn: (state.R[s].copy(), state.t[s].copy()) for s, pn in enumerate(self.pose_names)}
        if self.rig_index is not None:
            poses["prj_cam"] = (state.R_rig @ exp_so3(state.g[self.rig_index[:3]]),
                                state.g[self.rig_index[3:]].copy())
        warp = state.g[self.warp_index] if self.warp_index is not None else np.zeros(2)
        return RigState(K, dist, poses, np.array(warp))

    def theta(self, state: ParamState) -> np.ndarray:
        """Every parameter's value (``names`` order; rotation increments 0)."""
        return np.r_[state.g, np.c_[np.zeros((self.n_slots, 3)), state.t].ravel()]


POSE_PARAMS = ("w0", "w1", "w2", "t0", "t1", "t2")


def _global_layout(devices, start: RigState, config: BAConfig):
    """Global parameters: (names, values, free, {device: intrinsic indices}, rig index, warp index)."""
    names, values, free = [], [], []

    def add(name, value, is_free):
        names.append(name)
        values.append(float(value))
        free.append(bool(is_free))
        return len(names) - 1

    intr = {}
    for d in devices:
        dc = config.device(d)
        K = start.K[d]
        vals = (K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1] if dc.estimate_skew else 0.0)
        d0 = np.zeros(dc.n_distortion)
        given = np.asarray(start.dist.get(d, np.zeros(0)), float)
        d0[:min(given.size, d0.size)] = given[:d0.size]
        pairs = list(zip(INTRINSIC_NAMES, vals)) + list(zip(DISTORTION_NAMES, d0))
        intr[d] = np.array([add(f"{d}.{n}", dc.value(n, v), not dc.is_fixed(n)) for n, v in pairs])
    rig_index = None
    if config.mode == "joint":
        if "prj_cam" not in start.poses:
            raise BundleAdjustmentError("starting state lacks pose 'prj_cam'")
        t_rig = start.poses["prj_cam"][1]
        rig_index = np.array([add(f"prj_cam.w{j}", 0.0, True) for j in range(3)] +
                             [add(f"prj_cam.t{j}", t_rig[j], True) for j in range(3)])
    warp_index = None
    if config.board_warp:
        warp_index = np.array([add(f"board_warp.c{a}", start.warp[j], True) for j, a in enumerate("xy")])
    return names, values, np.array(free), intr, rig_index, warp_index


def _point_layout(obs, devices, start: RigState, config: BAConfig) -> dict:
    """Pose blocks and observed points, grouped by (view, device); each point's padded position."""
    slot_of, pose_names, blocks = {}, [], []      # blocks: (device, view, board point indices, pose)
    for i, v in enumerate(obs.views):
        for d in devices:
            pts = np.flatnonzero(v.seen(d))
            if len(pts) == 0:
                continue
            pn = f"cam_board/{i}" if config.mode == "joint" else f"{d}_board/{i}"
            if pn not in slot_of:
                if pn not in start.poses:
                    raise BundleAdjustmentError(f"starting state lacks pose {pn!r} (view {i} has "
                                                f"{len(pts)} {d} point(s); a pose needs at least 6)")
                slot_of[pn] = len(pose_names)
                pose_names.append(pn)
            blocks.append((d, i, pts, pn))
    if not blocks:
        raise BundleAdjustmentError("no observed point to adjust")
    counts = np.zeros(len(pose_names), int)
    cols = {k: [] for k in ("device", "view", "id", "sigma", "position", "slot", "X", "q")}
    first, k0 = {}, 0                             # (device, view) -> (board point indices, first point)
    for d, i, pts, pn in blocks:
        s, v, n = slot_of[pn], obs.views[i], len(pts)
        for key, value in (("device", [d] * n), ("view", np.full(n, i)), ("id", v.ids[pts]),
                           ("sigma", v.sigma[d][pts]), ("position", counts[s] + np.arange(n)),
                           ("slot", np.full(n, s)), ("X", v.points_board[pts]), ("q", v.q[d][pts])):
            cols[key].append(value)
        first[(d, i)] = (pts, k0)
        counts[s] += n
        k0 += n
    out = {k: np.concatenate(c) for k, c in cols.items()}
    out.update(pose_names=pose_names, first=first, P_max=int(counts.max()))
    out["pad"] = out["slot"] * out["P_max"] + out["position"]
    allX = np.concatenate([v.points_board for v in obs.views])
    half = np.maximum((allX[:, :2].max(0) - allX[:, :2].min(0)) / 2, 1e-9)
    mid = (allX[:, :2].max(0) + allX[:, :2].min(0)) / 2
    out["warp_basis"] = 1 - ((out["X"][:, :2] - mid) / half) ** 2
    return out


def _transfer_links(obs, first: dict):
    """(projector points, their camera points, A (T, 2, 2)) of the camera error transfer, or None."""
    prj_k, cam_k, As = [], [], []
    for (d, i), (pts, k) in first.items():
        v = obs.views[i]
        if d != "projector" or v.dprj_dcam is None or ("camera", i) not in first:
            continue
        c_pts, c_k0 = first[("camera", i)]
        A = v.dprj_dcam[pts]
        cols = np.minimum(np.searchsorted(c_pts, pts), len(c_pts) - 1)   # c_pts is sorted
        linked = (c_pts[cols] == pts) & np.all(np.isfinite(A), axis=(1, 2))
        prj_k.append(k + np.flatnonzero(linked))
        cam_k.append(c_k0 + cols[linked])
        As.append(A[linked])
    if not prj_k or not sum(len(a) for a in prj_k):
        return None
    return np.concatenate(prj_k), np.concatenate(cam_k), np.concatenate(As)


def build_problem(obs, start: RigState, config: BAConfig) -> BAProblem:
    """Lay out the adjustment of ``obs`` (``calib.observations.Observations``).

    ``start`` gives intrinsics and poses (see ``RigState``); the layout follows ``config``. The
    residual kernels are compiled once per model structure and cached (``calib.adjustment.kernel``).
    """
    from .kernel import KernelSpec, point_kernel

    t0 = time.perf_counter()
    devices = [d for d in ("camera", "projector") if obs.count(d) > 0]
    if config.mode == "joint" and devices != ["camera", "projector"]:
        raise BundleAdjustmentError(f"joint mode needs camera and projector observations; have {devices}")
    names, values, global_free, intr, rig_index, warp_index = _global_layout(devices, start, config)
    free_pos = np.cumsum(global_free) - 1          # position of a free global among the free ones
    pts = _point_layout(obs, devices, start, config)
    groups = []
    for d in devices:
        chain = 2 if (config.mode == "joint" and d == "projector") else 1
        spec = KernelSpec(config.device(d).n_distortion, chain)
        idx = np.flatnonzero(pts["device"] == d)
        jmap = np.full(spec.n_local, -1, dtype=np.int64)
        a, _ = spec.local_blocks["pose1"]
        jmap[a:a + 6] = -2 - np.arange(6)
        local = {"intr": intr[d], "warp": warp_index, "pose2": rig_index if chain == 2 else None}
        for block, gidx in local.items():
            if gidx is not None:
                a, b = spec.local_blocks[block]
                jmap[a:b] = np.where(global_free[gidx], free_pos[gidx], -1)
        groups.append(_PointGroup(d, point_kernel(spec, config.backend), idx, pts["slot"][idx], pts["pad"][idx],
                                  pts["X"][idx], pts["warp_basis"][idx], pts["q"][idx], intr[d], jmap))
    transfer = _transfer_links(obs, pts["first"]) if config.mode == "joint" and config.camera_error_transfer \
        else None
    pose_names = pts["pose_names"]
    S = len(pose_names)
    start_state = ParamState(np.array(values), start.poses["prj_cam"][0].copy() if rig_index is not None else None,
                             np.array([start.poses[pn][0] for pn in pose_names], float).reshape(S, 3, 3),
                             np.array([start.poses[pn][1] for pn in pose_names], float).reshape(S, 3))
    problem = BAProblem(config, obs, names, global_free, pose_names, start_state, groups, pts["P_max"],
                        len(pts["device"]), pts["sigma"], pts["device"], pts["view"], pts["id"], pts["pad"],
                        rig_index, warp_index, 0.0, "+".join(sorted({g.kernel.backend for g in groups})),
                        *(transfer or (None, None, None)))
    problem.build_seconds = time.perf_counter() - t0
    return problem
