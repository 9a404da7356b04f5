"""Reprojection of one calibration's board observations through another calibration.

For every view, a board pose in the world frame is fitted (Levenberg-Marquardt, float64) to the
observed camera AND projector pixels through the other calibration's rig (its intrinsics,
distortion, skew and camera-projector pose); the residual RMS per device says how well that rig
explains the observations. Seeded by OpenCV's PnP on the camera pixels.
"""
from __future__ import annotations

import numpy as np

from calib.rotation import matrix_from_rotvec, rotvec_from_matrix
from calib.system import SystemModel


def _fit_pose(system: SystemModel, view):
    import cv2
    from scipy.optimize import least_squares

    X = view.points_board
    devices = [(k, getattr(system, k), view.pixels[k]) for k in ("camera", "projector") if k in view.pixels]
    cam = system.camera
    q_cam = view.pixels.get("camera")
    ok = np.all(np.isfinite(q_cam), axis=1)
    K = np.array(cam.K)
    K[0, 1] = 0.0
    _, rvec, tvec = cv2.solvePnP(X[ok], q_cam[ok], K, cam.distortion if cam.distortion.size else None,
                                 flags=cv2.SOLVEPNP_ITERATIVE)
    # seed: board -> camera; world pose of the board: board -> world = cam^-1 * (board -> cam)
    R_cb = matrix_from_rotvec(rvec.ravel())
    R_wb = cam.R.T @ R_cb
    t_wb = cam.R.T @ (tvec.ravel() - cam.t)

    def residuals(x):
        R = matrix_from_rotvec(x[:3])
        Xw = X @ R.T + x[3:]
        out = []
        for _, dev, q in devices:
            r = dev.project(Xw) - q
            out.append(np.where(np.isfinite(r), r, 0.0).ravel())
        return np.concatenate(out)

    sol = least_squares(residuals, np.concatenate([rotvec_from_matrix(R_wb), t_wb]), method="lm", xtol=1e-14, ftol=1e-14)
    R = matrix_from_rotvec(sol.x[:3])
    Xw = X @ R.T + sol.x[3:]
    return {k: dev.project(Xw) - q for k, dev, q in devices}


def cross_reprojection(observations_of, through: SystemModel) -> dict:
    """RMS (px) per device and per view of ``observations_of``'s views through ``through``'s rig."""
    per_view = {"camera": [], "projector": []}
    all_res = {"camera": [], "projector": []}
    for view in observations_of.views:
        res = _fit_pose(through, view)
        for kind, r in res.items():
            r = r[np.all(np.isfinite(r), axis=1)]
            per_view[kind].append(float(np.sqrt(np.mean(np.sum(r ** 2, axis=1)))))
            all_res[kind].append(r)
    out = {"per_view_rms_px": per_view}
    out["rms_px"] = {k: float(np.sqrt(np.mean(np.sum(np.concatenate(v) ** 2, axis=1)))) for k, v in all_res.items() if v}
    out["residuals"] = {k: np.concatenate(v) for k, v in all_res.items() if v}
    return out
