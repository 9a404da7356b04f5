"""Calibration from point observations: Zhang seeds, stereo pose, bundle adjustment, system model.

``run_calibration(obs, config)`` is what ``calib run`` calls: it seeds each device with
``calib.zhang.init_device``, composes the projector-from-camera pose from the per-view seeds
(joint mode), adjusts everything with ``calib.adjustment.problem`` and returns the system in the
DESIGN.md convention, world = the board at the first view (as the paper's tables), together with
the adjustment's uncertainties and residuals.

SYNOPSIS (the paper's own observations: ``from_bouguet("CamCalibResult_real.mat",
"PrjCalibResult_real.mat")``; here simulated, noise-free, so the truth comes back)

    >>> import numpy as np
    >>> from calib import default_system
    >>> from calib.board import Board
    >>> from calib.adjustment.problem import BAConfig
    >>> from calib.calibrate import run_calibration
    >>> from calib.simulate import simulate_observations
    >>> s = default_system().ideal()          # no skew: the default model holds it at 0
    >>> obs, _ = simulate_observations(s, Board("checkerboard", 5, 7, 20.0), 6, 0.0, np.random.default_rng(0))
    >>> cal = run_calibration(obs, BAConfig(outlier_threshold=None))
    >>> round(cal.system.projector.fy / s.projector.fy, 6)
    1.0
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace

import numpy as np

from .adjustment.solver import BAResult, solve
from .adjustment.problem import BAConfig, RigState, build_problem
from .device import DeviceModel
from .observations import ObservationError, Observations
from .rotation import matrix_from_rotvec, nearest_rotation, rotvec_from_matrix
from .system import SystemModel
from .zhang import init_device

log = logging.getLogger(__name__)


@dataclass
class Calibration:
    """Result of ``run_calibration``.

    - system: SystemModel (world = board at view 0; in single mode each device's own view-0 pose).
    - ba: BAResult (uncertainties, residuals, rejected points, timings).
    - seeds: {device: DeviceSeed}; timings: {"init_s", "build_s", "solve_s", "total_s"}.
    - baseline_scatter_mm: spread (std, mm) of the projector centre in the camera frame over the
      per-view seed compositions (what a rig built from independent per-device poses suffers).
    - config: the :class:`calib.adjustment.problem.BAConfig` it was solved with
      (``outlier_threshold``: the rejection rule's threshold in robust sigmas, None: no rejection).
    - view_noise: {device: {view index: noise factor}} of the views :func:`reweight_views` gave
      their own noise level (None when it did not run).
    - uncertainty: None, or what :mod:`calib.uncertainty.assess` added (the error model's standard
      deviations, resampled spreads, warnings), set by :func:`calib.pipeline.calibrate_observations`.
    """

    system: SystemModel
    ba: BAResult
    seeds: dict
    timings: dict
    baseline_scatter_mm: float | None
    config: BAConfig | None = None
    view_noise: dict | None = None
    uncertainty: object = None

    @property
    def outlier_threshold(self) -> float | None:
        """The rejection rule's threshold in robust sigmas (None: no rejection)."""
        return None if self.config is None else self.config.outlier_threshold


def _average_rotation(Rs):
    return nearest_rotation(np.mean(Rs, axis=0))[0]


def start_state(obs: Observations, seeds: dict, config: BAConfig):
    """Starting RigState from per-device seeds; also the per-view baseline scatter (mm)."""
    K = {d: s.K for d, s in seeds.items()}
    dist = {d: s.distortion for d, s in seeds.items()}
    poses = {}
    scatter = None
    view_maps = {d: [i for i, v in enumerate(obs.views) if v.seen(d).sum() >= 6] for d in seeds}
    if config.mode == "single":
        for d, s in seeds.items():
            for k, i in enumerate(view_maps[d]):
                poses[f"{d}_board/{i}"] = (matrix_from_rotvec(s.rvec_dev_board[k]), s.t_dev_board[k])
        return RigState(K, dist, poses), scatter
    cam, prj = seeds["camera"], seeds["projector"]
    cam_views = view_maps["camera"]
    for k, i in enumerate(cam_views):
        poses[f"cam_board/{i}"] = (matrix_from_rotvec(cam.rvec_dev_board[k]), cam.t_dev_board[k])
    Rs, ts, centres = [], [], []
    for kp, i in enumerate(view_maps["projector"]):
        if i not in cam_views:
            continue
        kc = cam_views.index(i)
        Rc, tc = matrix_from_rotvec(cam.rvec_dev_board[kc]), cam.t_dev_board[kc]
        Rp, tp = matrix_from_rotvec(prj.rvec_dev_board[kp]), prj.t_dev_board[kp]
        R = Rp @ Rc.T
        t = tp - R @ tc
        Rs.append(R)
        ts.append(t)
        centres.append(-R.T @ t)
    if not Rs:
        raise ObservationError("no view is seen by both camera and projector: the rig pose cannot be found")
    poses["prj_cam"] = (_average_rotation(np.array(Rs)), np.median(np.array(ts), axis=0))
    c = np.array(centres)
    scatter = float(np.sqrt(np.mean(np.sum((c - c.mean(0)) ** 2, axis=1)))) if len(c) > 1 else None
    # views seen by the projector only get a board pose from the projector seed and the rig pose
    Rpc, tpc = poses["prj_cam"]
    for kp, i in enumerate(view_maps["projector"]):
        if f"cam_board/{i}" not in poses:
            Rp, tp = matrix_from_rotvec(prj.rvec_dev_board[kp]), prj.t_dev_board[kp]
            poses[f"cam_board/{i}"] = (Rpc.T @ Rp, Rpc.T @ (tp - tpc))
    return RigState(K, dist, poses), scatter


def _device(d, size, K, dist, R, t):
    return DeviceModel(size=tuple(size), K=K, distortion=dist, R=R, t=t, kind=d, name=d)


def system_from_result(obs: Observations, res: BAResult) -> SystemModel:
    """SystemModel with world = board at the first view that has a pose."""
    st = res.state
    meta = {"world": None}
    if res.mode == "joint":
        i0 = min(int(pn.split("/")[1]) for pn in st.poses if pn.startswith("cam_board/"))
        Rc, tc = st.poses[f"cam_board/{i0}"]
        Rpc, tpc = st.poses["prj_cam"]
        cam = _device("camera", obs.sizes["camera"], st.K["camera"], st.dist["camera"], Rc, tc)
        prj = _device("projector", obs.sizes["projector"], st.K["projector"], st.dist["projector"],
                      Rpc @ Rc, Rpc @ tc + tpc)
        meta["world"] = f"board at view {i0} ({obs.views[i0].name})"
        return SystemModel(cam, prj, meta)
    devs = {}
    for d in st.K:
        i0 = min(int(pn.split("/")[1]) for pn in st.poses if pn.startswith(f"{d}_board/"))
        R, t = st.poses[f"{d}_board/{i0}"]
        devs[d] = _device(d, obs.sizes[d], st.K[d], st.dist[d], R, t)
        meta[f"world_{d}"] = f"board at view {i0} ({obs.views[i0].name}), this device's own pose"
    if len(devs) == 1:  # one device: the other slot is filled by an identical copy, marked as such
        d = next(iter(devs))
        meta["only_device"] = d
        other = "projector" if d == "camera" else "camera"
        devs[other] = devs[d].with_(kind=other, name=other)
    return SystemModel(devs["camera"], devs["projector"], meta)


def run_calibration(obs: Observations, config: BAConfig | None = None) -> Calibration:
    """Seed + adjust (see the module docstring). Raises a ValueError subclass on failure.

    Progress goes to the ``calib`` logger, or to ``config.progress`` (a callable taking one line)
    when it is set."""
    config = config or BAConfig()
    say = config.progress or log.info
    config = replace(config, progress=say)   # the adjustment reports through the same sink
    t0 = time.perf_counter()
    devices = obs.devices()
    if not devices:
        raise ObservationError("no device has any observation")
    if config.mode == "joint" and len(devices) < 2:
        raise ObservationError(f"joint calibration needs camera and projector observations; only {devices} "
                               "given (use mode='single')")
    for d in devices:
        n_ok = sum(1 for v in obs.views if v.seen(d).sum() >= 6)
        if n_ok < 3:
            raise ObservationError(f"{d}: {n_ok} view(s) with >= 6 observed points; at least 3 views in "
                                   "different orientations are needed")
    seeds = {}
    for d in devices:
        views = [v for v in obs.views if v.seen(d).sum() >= 6]
        say(f"seeding {d}: Zhang closed form on {len(views)} view(s)")
        seeds[d] = init_device([v.points_board[v.seen(d)] for v in views],
                               [v.q[d][v.seen(d)] for v in views], obs.sizes[d],
                               n_distortion=config.device(d).n_distortion, refine=False, label=d)
        say(f"  {d} seed: fx {seeds[d].K[0, 0]:.2f} fy {seeds[d].K[1, 1]:.2f} cx {seeds[d].K[0, 2]:.2f}"
                     f" cy {seeds[d].K[1, 2]:.2f}, RMS {seeds[d].rms_px:.4f} px")
    t_init = time.perf_counter() - t0
    state, scatter = start_state(obs, seeds, config)
    say(f"building the {config.mode} adjustment")
    problem = build_problem(obs, state, config)
    say(f"  {int(problem.free.sum())} parameters, {2 * problem.n_points} residuals "
                 f"(built in {problem.build_seconds:.2f} s); solving")
    res = solve(problem)
    system = system_from_result(obs, res)
    timings = {"init_s": t_init, "build_s": problem.build_seconds, "solve_s": res.timings["solve_s"],
               "total_s": time.perf_counter() - t0}
    return Calibration(system, res, seeds, timings, scatter, config)


#: A view whose robust residual level exceeds the median view's by this factor gets its own noise
#: level in :func:`reweight_views` (35 points per view estimate a level to about 10 %). The paper's
#: observations have projector views at 5.5, 3.6 and 2.1x; the SLStudio example's worst is 1.7x,
#: where reweighting (at 1.5) moved camera k1 by 1.6 sigma and did not reduce the rejections
#: (15 -> 25, their tails are not one view's noise): only views clearly noisier count.
VIEW_NOISE_RATIO = 2.0


def sigma_of_points(obs: Observations, ba: BAResult) -> np.ndarray:
    """(P,) the observations' sigma (px) of every point of an adjustment, in its point order."""
    table = {}
    for i, v in enumerate(obs.views):
        for d in v.q:
            sig = v.sigma.get(d, np.ones(len(v.points_board)))
            table.update({(i, d, int(k)): float(s) for k, s in zip(v.ids, sig)})
    return np.array([table[(int(i), str(d), int(k))]
                     for i, d, k in zip(ba.point_view, ba.point_device, ba.point_id)])


def view_noise_factors(cal: Calibration, obs: Observations, ratio: float = VIEW_NOISE_RATIO) -> dict:
    """{device: {view: factor}} of the views whose robust residual level (per coordinate, from the
    median of the squared normalised residual norms) is more than ``ratio`` times the median
    view's of the same device; factor = that level / the median view's."""
    ba = cal.ba
    out = {}
    for d in np.unique(ba.point_device):
        m = ba.point_device == d
        e = np.linalg.norm(ba.residuals_px[m], axis=1) / sigma_of_points(obs, ba)[m]
        views = ba.point_view[m]
        level = {int(v): float(np.sqrt(np.median(e[views == v] ** 2) / (2 * np.log(2)))) for v in np.unique(views)}
        typical = float(np.median(list(level.values())))
        noisy = {v: lv / typical for v, lv in level.items() if typical > 0 and lv > ratio * typical}
        if noisy:
            out[str(d)] = noisy
    return out


def reweight_views(obs: Observations, config: BAConfig | None = None, *, ratio: float = VIEW_NOISE_RATIO
                   ) -> Calibration:
    """:func:`run_calibration`, then again with each noisy view's points weighted by its own noise.

    One noise level per device assumes every view is measured equally well. On the paper's real
    observations two of nine views carry 3-4x the projector residual of the others (bench
    ``python -m bench.outlier_rule``); pooled, the default 5-sigma rule then rejects 25 of their
    points although they are that view's noise, not gross errors. Here the views whose robust
    residual level exceeds ``ratio`` times the median view's (:func:`view_noise_factors`) get
    their points' sigma multiplied by that factor and the adjustment is run again; the outlier
    rule then judges each point against its own view's noise. ``Calibration.view_noise`` lists
    the factors ({} when no view stood out: the first result is returned).
    """
    config = config or BAConfig()
    first = run_calibration(obs, config)
    factors = view_noise_factors(first, obs, ratio)
    if not factors:
        first.view_noise = {}
        return first
    (config.progress or log.info)("views with their own noise level: " + "; ".join(
        f"{d} view(s) {', '.join(f'{v + 1} (x{f:.2f})' for v, f in fv.items())}" for d, fv in factors.items()))
    cal = run_calibration(with_view_noise(obs, factors), config)
    cal.view_noise = factors
    return cal


def with_view_noise(obs: Observations, factors: dict) -> Observations:
    """``obs`` with the points' sigma of view i of device d multiplied by ``factors[d][i]``
    (:func:`view_noise_factors`; views not listed keep theirs)."""
    views = []
    for i, v in enumerate(obs.views):
        sigma = {d: np.asarray(v.sigma.get(d, np.ones(len(v.points_board))), dtype=np.float64)
                 * factors.get(d, {}).get(i, 1.0) for d in v.q}
        views.append(replace(v, sigma=sigma))
    return replace(obs, views=views)


__all__ = ["Calibration", "run_calibration", "reweight_views", "view_noise_factors", "with_view_noise", "sigma_of_points",
           "start_state", "system_from_result", "rotvec_from_matrix"]
