"""Does a session's reported sigma hold when one pose is left out? The nested leave-one-pose-out check.

For a session of n poses, the calibration of all n (the reported sigma ``sigma_j`` of every
parameter j, :mod:`calib.uncertainty.assess`) is compared with the calibrations of the n sessions of n - 1
poses:

    z_ij = (theta_j(without pose i) - theta_j(all)) / sigma_j.

With honest sigmas and poses of equal leverage, the estimate of n - 1 poses scatters about the one
of n by ``sigma_j sqrt(n / (n - 1) - 1) = sigma_j / sqrt(n - 1)`` (nested estimators: the variance
of the difference is the difference of the variances), so the RMS of z is ``1 / sqrt(n - 1)``:
0.5 for 5 poses, 0.45 for 6. A value well above that says the sigmas are too small, well below too
large. Unequal leverage raises it (a pose that alone pins a parameter moves it a lot when left
out: on a model of the SLStudio session the jackknife overstates by 1.1-1.2x, docs/calib.md), so the
ratio ``rms_z * sqrt(n - 1)`` ("normalised") is read with that in mind: 1 is honest, 1.2 still is.

What honest sigmas give on a given session is computed too (``expected``): the fit linearised at
the full solution, the shift of leaving pose i out is ``K_i e`` with
``K_i = (J_-i^T J_-i)^-1 J_-i^T P_-i - (J^T J)^-1 J^T`` (rows and board-pose columns of pose i
dropped), so under the fitted error model ``E[shift^2] = diag(K_i Omega K_i^T)``, and the expected
``z^2`` is that over the model's own variance (before the few-pose inflation). It carries the
session's unequal leverage; ``rms / expected_rms`` near 1 is honest.

"Nested": each session of n - 1 poses is itself checked against its own n - 2 subsets when asked
(``depth=2``), which is how a 5-pose session is measured from a 6-pose one.

The parameters compared are those the issue names: fx, fy, cx, cy of both devices and the rig
translation ``prj_cam.t0..2`` (where estimated).

SYNOPSIS (not run: a few seconds per calibration)

    from calib.uncertainty.pose_holdout import holdout_z
    res = holdout_z(obs)                     # Observations of one session
    res.rms, res.max, res.normalised
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..observations import Observations

PARAMETERS = tuple(f"{d}.{p}" for d in ("camera", "projector") for p in ("fx", "fy", "cx", "cy")) + tuple(
    f"prj_cam.t{j}" for j in range(3))


@dataclass
class HoldoutZ:
    """Leave-one-pose-out shifts in units of the reported sigma (module docstring).

    - n_poses; z: (n_poses, P) array (rows: the pose left out; NaN where a run failed);
      names (P,); rms, max: over all finite entries; normalised: ``rms * sqrt(n - 1)`` (1: honest).
    - reported: {name: sigma} of the full session; too_small: the report's own verdict (if any).
    """

    n_poses: int
    names: list
    z: np.ndarray
    reported: dict
    too_small: bool | None = None
    sub: list = field(default_factory=list)
    expected: np.ndarray | None = None
    poses: tuple = ()

    @property
    def expected_rms(self) -> float:
        """RMS z that honest sigmas give on this session (linearised, fitted error model); NaN
        where the error model was not computed."""
        if self.expected is None:
            return float("nan")
        return float(np.sqrt(np.mean(self.expected[np.isfinite(self.z)])))

    @property
    def rms(self) -> float:
        v = self.z[np.isfinite(self.z)]
        return float(np.sqrt(np.mean(v ** 2))) if v.size else float("nan")

    @property
    def max(self) -> float:
        v = self.z[np.isfinite(self.z)]
        return float(np.max(np.abs(v))) if v.size else float("nan")

    @property
    def normalised(self) -> float:
        return self.rms * np.sqrt(self.n_poses - 1)


def calibrate_with_uncertainty(obs: Observations, config=None):
    """What ``calib run`` computes for the uncertainty, without writing anything: the board warp
    resolved for these views, per-view noise levels, then :func:`calib.uncertainty.assess.assess_uncertainty`
    on the observations as that adjustment weighted them. Returns the Calibration (``.uncertainty``)."""
    from ..adjustment.problem import BAConfig
    from ..calibrate import reweight_views, with_view_noise
    from ..pipeline import resolve_board_warp
    from .assess import assess_uncertainty

    config = resolve_board_warp(replace(config or BAConfig(), progress=lambda s: None), obs, "auto")
    cal = reweight_views(obs, config)
    fitted = with_view_noise(obs, cal.view_noise) if cal.view_noise else obs
    cal.uncertainty = assess_uncertainty(cal, fitted)
    cal.uncertainty_observations = fitted
    return cal


def subset(obs: Observations, keep) -> Observations:
    """The session of the poses ``keep`` (indices)."""
    return Observations([obs.views[i] for i in keep], dict(obs.sizes), obs.source)


def holdout_z(obs: Observations, config=None, *, depth: int = 1, names=PARAMETERS, _cache=None) -> HoldoutZ:
    """Nested leave-one-pose-out z of ``obs`` (module docstring); ``depth=2`` also measures every
    (n - 1)-pose session against its own subsets (``.sub``). Calibrations are shared between the
    levels (a cache keyed by the poses kept)."""
    from .resampling import system_parameters

    cache = {} if _cache is None else _cache

    def fit(keep):
        key = tuple(keep)
        if key not in cache:
            try:
                cache[key] = calibrate_with_uncertainty(subset(obs, keep), config)
            except ValueError as exc:          # a subset that does not determine the model
                cache[key] = exc
        return cache[key]

    return _holdout(list(range(len(obs.views))), fit, depth, names, system_parameters)


def _holdout(keep, fit, depth, names, system_parameters) -> HoldoutZ:
    full = fit(keep)
    if isinstance(full, Exception):
        raise full
    R_ref = full.ba.state.poses["prj_cam"][0] if "prj_cam" in full.ba.state.poses else None
    theta = system_parameters(full, R_ref)
    std = full.uncertainty.std
    names = [n for n in names if n in theta and std.get(n)]
    z = np.full((len(keep), len(names)), np.nan)
    sub = []
    for i, drop in enumerate(keep):
        rest = [k for k in keep if k != drop]
        cal = fit(rest)
        if isinstance(cal, Exception):
            continue
        est = system_parameters(cal, R_ref)
        z[i] = [(est[n] - theta[n]) / std[n] for n in names]
        if depth > 1 and len(rest) >= 4:
            sub.append(_holdout(rest, fit, depth - 1, names, system_parameters))
    small = full.uncertainty.too_small
    return HoldoutZ(len(keep), names, z, {n: std[n] for n in names}, small, sub, _expected(full, names), tuple(keep))


def _expected(cal, names):
    """(n_poses, P) expected z^2 under the fitted error model (module docstring), or None."""
    from .pose_error_model import _field_matrices
    from ..adjustment.jacobian import adjustment_jacobian

    em = cal.uncertainty.error_model
    if em is None or em.components is None:
        return None
    fitted = cal.uncertainty_observations
    aj = adjustment_jacobian(cal, fitted)
    mats, labels, rows = _field_matrices(aj, fitted)
    _, S, s0 = em.components
    J = aj.J[rows]
    J = J.toarray() if hasattr(J, "toarray") else np.asarray(J)   # the adjustment's J is sparse; a check: dense
    B = np.linalg.inv(J.T @ J)
    cols = [aj.names.index(n) for n in names]
    base = (B @ J.T)[cols]
    view = np.repeat(aj.view, 2)[rows]
    inflation = dict(zip(em.names, em.levels.inflation)) if em.levels is not None else {}
    v = np.array([(em.std[n] / inflation.get(n, 1.0)) ** 2 for n in names])
    out = np.full((len(fitted.views), len(names)), np.nan)
    for i in range(len(fitted.views)):
        keep_r = view != i
        keep_c = [k for k, n in enumerate(aj.names) if not ("/" in n and n.split("/")[1].split(".")[0] == str(i))]
        Ji = J[np.ix_(keep_r, keep_c)]
        K = -base.copy()
        K[:, keep_r] += (np.linalg.inv(Ji.T @ Ji) @ Ji.T)[[keep_c.index(c) for c in cols]]
        var = s0 * np.sum(K ** 2, axis=1) + sum(s * np.sum((K @ A) ** 2, axis=1) for s, A in zip(S, mats) if s > 0)
        out[i] = var / v
    return out
