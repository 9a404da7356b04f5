"""Synthetic board observations of a known system (for tests, hard cases and benchmarks).

``simulate_observations(system, board, n_views, noise_px, rng)`` places the board at ``n_views``
poses around the system's world origin (the paper's world is the board at pose 1, in front of
both devices), tilted by ``tilt_deg`` about varied axes, projects the board points through both
full device models and adds Gaussian pixel noise. Points outside an image are NaN (not seen).

SYNOPSIS

    >>> import numpy as np
    >>> from calib import default_system
    >>> from calib.board import Board
    >>> from calib.simulate import simulate_observations
    >>> obs, poses = simulate_observations(default_system(), Board("checkerboard", 5, 7, 20.0), 4,
    ...                                    0.1, np.random.default_rng(0))
    >>> len(obs.views)
    4
"""
from __future__ import annotations

import numpy as np

from .observations import Observations, ViewObservations
from .rotation import matrix_from_rotvec


def board_poses_world(n_views: int, rng, *, tilt_deg=(15.0, 35.0), shift_mm: float = 20.0,
                      depth_mm: float = 40.0):
    """(R_world_board, t_world_board) list: tilted, shifted copies of the world's board pose."""
    poses = []
    for i in range(n_views):
        az = 2 * np.pi * (i / max(n_views, 1)) + rng.uniform(-0.3, 0.3)
        tilt = np.radians(rng.uniform(*tilt_deg)) if tilt_deg[1] > 0 else 0.0
        axis = np.array([np.cos(az), np.sin(az), 0.0])
        spin = np.radians(rng.uniform(-10, 10))
        R = matrix_from_rotvec(axis * tilt) @ matrix_from_rotvec([0, 0, spin])
        t = np.array([rng.uniform(-shift_mm, shift_mm), rng.uniform(-shift_mm, shift_mm),
                      rng.uniform(-depth_mm, depth_mm)])
        poses.append((R, t))
    return poses


def projector_pixels_at_camera_pixels(system, R_world_board, t_world_board, q_cam):
    """Where the projector lights the board point seen at camera pixels ``q_cam`` (N, 2): the
    camera ray of each pixel met with the board plane, projected by the projector. What a phase
    decoder reads at those camera pixels, noise-free. Returns (N, 2) projector px (NaN where the
    ray misses the plane or the lens cannot be inverted)."""
    origin, d, ok = system.camera.rays_world(q_cam)
    n = R_world_board[:, 2]
    denom = d @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((t_world_board - origin) @ n) / denom
    ok = ok & np.isfinite(s) & (s > 0)
    Xw = origin + s[:, None] * d
    out = system.projector.project(np.where(ok[:, None], Xw, 0.0))
    out[~ok] = np.nan
    return out


def projector_readout_jacobian(system, R_world_board, t_world_board, q_cam, h_px: float = 1e-3):
    """(N, 2, 2) ``d q_prj / d q_cam`` of :func:`projector_pixels_at_camera_pixels` at ``q_cam``
    (N, 2), by central differences of step ``h_px``: rows u_p, v_p; columns x, y (camera px)."""
    q_cam = np.asarray(q_cam, dtype=np.float64)
    cols = []
    for step in ([h_px, 0.0], [0.0, h_px]):
        plus = projector_pixels_at_camera_pixels(system, R_world_board, t_world_board, q_cam + step)
        minus = projector_pixels_at_camera_pixels(system, R_world_board, t_world_board, q_cam - step)
        cols.append((plus - minus) / (2 * h_px))
    return np.stack(cols, axis=2)


def simulate_observations(system, board, n_views: int, noise_px, rng, *, tilt_deg=(15.0, 35.0),
                          poses=None, noise_prj_px=None, projector_from_camera: bool = False):
    """Observations of ``board`` by both devices of ``system`` and the true board -> camera poses.

    ``projector_from_camera`` False: both devices observe the board points independently
    (Gaussian noise ``noise_px`` / ``noise_prj_px``). True: as a phase-shifting system measures
    them: the camera pixel carries the detector's error (``noise_px``) and the projector pixel is
    read at that detected camera pixel (``projector_pixels_at_camera_pixels``) with a phase error
    ``noise_prj_px`` of its own, so the camera error carries into the projector pixel; the views
    then hold ``dprj_dcam``, the exact local derivative of that read-out (``projector_readout_jacobian``).

    RETURNED VALUE: (Observations, list of (R_cam_board, t_cam_board)).
    """
    noise_prj_px = noise_px if noise_prj_px is None else noise_prj_px
    poses = poses or board_poses_world(n_views, rng, tilt_deg=tilt_deg)
    X = board.points_board()
    views, truth = [], []
    for i, (Rwb, twb) in enumerate(poses):
        Xw = X @ Rwb.T + twb
        q = {}
        grad = None
        for d, dev, s in (("camera", system.camera, noise_px), ("projector", system.projector, noise_prj_px)):
            if d == "projector" and projector_from_camera:
                qc = np.where(np.isfinite(q["camera"]), q["camera"], 0.0)
                p = projector_pixels_at_camera_pixels(system, Rwb, twb, qc)
                grad = projector_readout_jacobian(system, Rwb, twb, qc)
                p[~np.isfinite(q["camera"][:, 0])] = np.nan
            else:
                p = dev.project(Xw)
            p = p + rng.normal(0.0, s, p.shape) if s > 0 else p
            w, h = dev.size
            out = ~((p[:, 0] > -0.5) & (p[:, 0] < w - 0.5) & (p[:, 1] > -0.5) & (p[:, 1] < h - 0.5))
            p[out] = np.nan
            q[d] = p
        sig = {"camera": np.full(len(X), 1.0), "projector": np.full(len(X), 1.0)}
        views.append(ViewObservations(X, q, sig, name=f"pose_{i:02d}", dprj_dcam=grad))
        Rc, tc = system.camera.R, system.camera.t
        truth.append((Rc @ Rwb, Rc @ twb + tc))
    return Observations(views, {"camera": system.camera.size, "projector": system.projector.size},
                        source="simulated"), truth
