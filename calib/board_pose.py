"""The pose of a board view fitted through a whole rig, and cross reprojection.

For one view, :func:`fit_board_pose` fits the board -> world pose (Levenberg-Marquardt, float64)
to the observed camera AND projector pixels through one calibration's rig (its intrinsics,
distortion, skew and camera-projector pose), seeded by OpenCV's PnP on the camera pixels; the
residuals say how well that rig explains the observations. :func:`cross_reprojection` does it for
every view of one calibration's observations through another calibration (the twin-equivalence
report's "cross reprojection").

SYNOPSIS

    >>> import numpy as np
    >>> from calib import default_system
    >>> from calib.board import Board
    >>> from calib.simulate import simulate_observations
    >>> from calib.board_pose import cross_reprojection
    >>> s = default_system()
    >>> obs, _ = simulate_observations(s, Board("checkerboard", 5, 7, 20.0), 3, 0.0, np.random.default_rng(1))
    >>> r = cross_reprojection(obs, s)
    >>> bool(r["rms_px"]["camera"] < 1e-6 and r["rms_px"]["projector"] < 1e-6)
    True
"""
from __future__ import annotations

import numpy as np

from .errors import ObservationError
from .rotation import matrix_from_rotvec, rotvec_from_matrix
from .system import SystemModel


def fit_board_pose(system: SystemModel, view):
    """Fit the board -> world pose of one view to both devices' pixels through ``system``.

    ARGUMENTS: system (the rig); view (:class:`calib.observations.ViewObservations` with camera
    pixels: they seed the pose).
    RETURNED VALUE: (R_world_board (3, 3), t_world_board (3,) mm, residuals {device: (N, 2) px,
    predicted - observed, NaN where a point was not observed}).
    """
    import cv2
    from scipy.optimize import least_squares

    X = view.points_board
    devices = [(k, getattr(system, k), view.q[k]) for k in ("camera", "projector") if k in view.q]
    cam = system.camera
    q_cam = view.q.get("camera")
    if q_cam is None:
        raise ObservationError(f"{view.name or 'view'}: no camera pixels to seed the board pose with")
    ok = np.all(np.isfinite(q_cam), axis=1)
    K = np.array(cam.K)
    K[0, 1] = 0.0
    _, rvec, tvec = cv2.solvePnP(X[ok], q_cam[ok], K, cam.distortion if cam.distortion.size else None,
                                 flags=cv2.SOLVEPNP_ITERATIVE)
    # seed: board -> camera; world pose of the board: board -> world = cam^-1 * (board -> cam)
    R_cam_board = matrix_from_rotvec(rvec.ravel())
    R_world_board = cam.R.T @ R_cam_board
    t_world_board = cam.R.T @ (tvec.ravel() - cam.t)

    def residuals(x):
        R = matrix_from_rotvec(x[:3])
        Xw = X @ R.T + x[3:]
        out = []
        for _, dev, q in devices:
            r = dev.project(Xw) - q
            out.append(np.where(np.isfinite(r), r, 0.0).ravel())
        return np.concatenate(out)

    sol = least_squares(residuals, np.concatenate([rotvec_from_matrix(R_world_board), t_world_board]), method="lm",
                        xtol=1e-14, ftol=1e-14)
    R = matrix_from_rotvec(sol.x[:3])
    Xw = X @ R.T + sol.x[3:]
    return R, sol.x[3:].copy(), {k: dev.project(Xw) - q for k, dev, q in devices}


def cross_reprojection(observations_of, through: SystemModel) -> dict:
    """RMS (px) per device and per view of ``observations_of``'s views (anything with ``.views``,
    e.g. :class:`calib.observations.Observations` or a :class:`calib.io.record.CalibrationRecord`)
    through ``through``'s rig.

    RETURNED VALUE: ``{"per_view_rms_px": {device: [...]}, "rms_px": {device: rms},
    "residuals": {device: (M, 2) px of the observed points}}``.
    """
    per_view = {"camera": [], "projector": []}
    all_res = {"camera": [], "projector": []}
    for view in observations_of.views:
        _, _, res = fit_board_pose(through, view)
        for kind, r in res.items():
            r = r[np.all(np.isfinite(r), axis=1)]
            per_view[kind].append(float(np.sqrt(np.mean(np.sum(r ** 2, axis=1)))))
            all_res[kind].append(r)
    out = {"per_view_rms_px": per_view}
    out["rms_px"] = {k: float(np.sqrt(np.mean(np.sum(np.concatenate(v) ** 2, axis=1)))) for k, v in all_res.items() if v}
    out["residuals"] = {k: np.concatenate(v) for k, v in all_res.items() if v}
    return out
