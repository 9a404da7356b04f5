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


def simulate_observations(system, board, n_views: int, noise_px, rng, *, tilt_deg=(15.0, 35.0),
                          poses=None, noise_prj_px=None):
    """Observations of ``board`` by both devices of ``system`` and the true board -> camera poses.

    RETURNED VALUE: (Observations, list of (R_cam_board, t_cam_board)).
    """
    noise_prj_px = noise_px if noise_prj_px is None else noise_prj_px
    poses = poses or board_poses_world(n_views, rng, tilt_deg=tilt_deg)
    X = board.points_board()
    views, truth = [], []
    for i, (Rwb, twb) in enumerate(poses):
        Xw = X @ Rwb.T + twb
        q = {}
        for d, dev, s in (("camera", system.camera, noise_px), ("projector", system.projector, noise_prj_px)):
            p = dev.project(Xw)
            p = p + rng.normal(0.0, s, p.shape) if s > 0 else p
            w, h = dev.size
            out = ~((p[:, 0] > -0.5) & (p[:, 0] < w - 0.5) & (p[:, 1] > -0.5) & (p[:, 1] < h - 0.5))
            p[out] = np.nan
            q[d] = p
        sig = {"camera": np.full(len(X), 1.0), "projector": np.full(len(X), 1.0)}
        views.append(ViewObservations(X, q, sig, name=f"pose_{i:02d}"))
        Rc, tc = system.camera.R, system.camera.t
        truth.append((Rc @ Rwb, Rc @ twb + tc))
    return Observations(views, {"camera": system.camera.size, "projector": system.projector.size},
                        source="simulated"), truth
