"""The same single-device calibration solved by mrcal (the peer we compare against).

``mrcal_calibrate(obs, device, n_distortion, seed)`` feeds one device's board observations to
``mrcal.optimize`` with regularisation and outlier rejection off, so that it minimises exactly
the cost our bundle adjustment minimises (sum of squared pixel residuals, weights 1/sigma):
both must reach the same intrinsics. mrcal's board frame has its origin at a corner of the grid
(point (i, j) at (j*spacing, i*spacing, 0)); our board points are mapped onto it by a shift,
which only changes the board poses.
"""
from __future__ import annotations

import time

import numpy as np

from .problem import BundleAdjustmentError
from ..rotation import rotvec_from_matrix

LENSMODELS = {0: "LENSMODEL_PINHOLE", 4: "LENSMODEL_OPENCV4", 5: "LENSMODEL_OPENCV5",
              8: "LENSMODEL_OPENCV8", 12: "LENSMODEL_OPENCV12"}


def board_grid(points_board):
    """Grid description of planar board points (N,3): (spacing, origin (2,), rows (N,), cols (N,), H, W)."""
    xy = points_board[:, :2]
    d = np.abs(np.diff(np.unique(np.round(xy[:, 0], 9))))
    spacing = float(d[d > 1e-9].min())
    origin = xy.min(axis=0)
    cols = np.rint((xy[:, 0] - origin[0]) / spacing).astype(int)
    rows = np.rint((xy[:, 1] - origin[1]) / spacing).astype(int)
    if np.max(np.abs(origin + np.c_[cols, rows] * spacing - xy)) > 1e-6 * spacing:
        raise BundleAdjustmentError("board points are not on a regular grid: mrcal cannot take them")
    return spacing, origin, rows, cols, rows.max() + 1, cols.max() + 1


def mrcal_calibrate(obs, device: str, n_distortion: int, K0, dist0, poses0):
    """Solve one device with mrcal.optimize; returns (intrinsics (4+n,), rms_px, seconds).

    ``poses0``: list of (R, t) board -> device seeds, one per view (same order as obs.views).
    """
    import mrcal

    allX = np.concatenate([v.points_board for v in obs.views])
    spacing, origin, _, _, H, W = board_grid(allX)
    nv = len(obs.views)
    observations = np.full((nv, H, W, 3), -1.0)
    observations[..., :2] = 0.0
    frames = np.zeros((nv, 6))
    for i, v in enumerate(obs.views):
        _, _, rows, cols, _, _ = board_grid(np.vstack([v.points_board, allX]))
        rows, cols = rows[:len(v.points_board)], cols[:len(v.points_board)]
        seen = v.seen(device)
        observations[i, rows[seen], cols[seen], :2] = v.q[device][seen]
        observations[i, rows[seen], cols[seen], 2] = 1.0 / v.sigma[device][seen]
        R, t = poses0[i]
        frames[i, :3] = rotvec_from_matrix(R)
        frames[i, 3:] = t + R @ np.array([origin[0], origin[1], 0.0])
    intrinsics = np.array([[K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2], *np.resize(dist0, n_distortion)]],
                          dtype=np.float64)
    if n_distortion == 0:
        intrinsics = intrinsics[:, :4]
    t0 = time.perf_counter()
    stats = mrcal.optimize(intrinsics, np.zeros((0, 6)), frames, None, observations,
                           np.array([[i, 0, -1] for i in range(nv)], dtype=np.int32), None, None,
                           LENSMODELS[n_distortion], imagersizes=np.array([obs.sizes[device]], np.int32),
                           calibration_object_spacing=spacing, do_optimize_intrinsics_core=True,
                           do_optimize_intrinsics_distortions=True, do_optimize_extrinsics=False,
                           do_optimize_frames=True, do_optimize_calobject_warp=False,
                           do_apply_outlier_rejection=False, do_apply_regularization=False,
                           verbose=False)
    seconds = time.perf_counter() - t0
    return intrinsics[0], float(stats["rms_reproj_error__pixels"]), seconds
