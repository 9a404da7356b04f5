"""Zhang initialisation of one device (camera, or projector as an inverse camera) from board views.

Seeding matters: OpenCV's ``calibrateCamera`` without a guess starts from one focal length and
the principal point at the image centre, which lands in a wrong minimum for the paper's
projector (fx 1732, fy 3463, cy 588 of 1140). Here the seed is Zhang's closed form with zero
skew, which estimates fx, fy, cx, cy separately from the view homographies; poses then come from
``cv2.solvePnP`` with that seed, and ``cv2.calibrateCamera`` refines (intrinsic guess kept,
distortion terms as asked). A set of views that leaves the intrinsics unobservable (all views
fronto-parallel, too few views) is refused with a message saying so.

SYNOPSIS

    >>> import numpy as np
    >>> from calib import default_system
    >>> from calib.board import Board
    >>> from calib.simulate import simulate_observations
    >>> from calib.zhang import init_device
    >>> s = default_system()
    >>> obs, _ = simulate_observations(s, Board("checkerboard", 5, 7, 20.0), 6, 0.0, np.random.default_rng(0))
    >>> seen = [v.seen("camera") for v in obs.views]
    >>> seed = init_device([v.points_board[m] for v, m in zip(obs.views, seen)],
    ...                    [v.q["camera"][m] for v, m in zip(obs.views, seen)], s.camera.size)
    >>> bool(abs(seed.K[0, 0] / s.camera.fx - 1) < 1e-3), bool(seed.rms_px < 1e-3)
    (True, True)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InitError

MIN_VIEWS = 3


@dataclass
class DeviceSeed:
    """Initial intrinsics and board poses of one device.

    - K (3,3), distortion (n,): intrinsics, px.
    - rvec_dev_board (V,3), t_dev_board (V,3): board -> device pose per view (rotation vector, mm).
    - rms_px: reprojection RMS of the seed; tilt_deg (V,): board tilt against the image plane.
    - method: how the seed was obtained.
    """

    K: np.ndarray
    distortion: np.ndarray
    rvec_dev_board: np.ndarray
    t_dev_board: np.ndarray
    rms_px: float
    tilt_deg: np.ndarray
    method: str


def _normalisation(p):
    """Similarity T (3,3) moving points (N,2) to zero mean and mean distance sqrt(2)."""
    m = p.mean(axis=0)
    d = np.mean(np.linalg.norm(p - m, axis=1))
    s = np.sqrt(2) / max(d, 1e-12)
    return np.array([[s, 0, -s * m[0]], [0, s, -s * m[1]], [0, 0, 1.0]])


def homography(xy_board, q) -> np.ndarray:
    """Normalised-DLT homography (3,3) mapping board (x, y) mm to pixels, H[2,2] = 1."""
    Ta, Tb = _normalisation(xy_board), _normalisation(q)
    a = (np.c_[xy_board, np.ones(len(q))] @ Ta.T)
    b = (np.c_[q, np.ones(len(q))] @ Tb.T)
    x, y, u, v = a[:, 0], a[:, 1], b[:, 0], b[:, 1]
    one, zero = np.ones_like(x), np.zeros_like(x)
    rows = np.empty((2 * len(x), 9))
    rows[0::2] = np.stack([x, y, one, zero, zero, zero, -u * x, -u * y, -u], axis=1)
    rows[1::2] = np.stack([zero, zero, zero, x, y, one, -v * x, -v * y, -v], axis=1)
    _, _, vt = np.linalg.svd(rows, full_matrices=False)  # vt only: thin SVD
    Hn = vt[-1].reshape(3, 3)
    s = Tb[0, 0]                                        # Tb^-1 of the similarity Tb, in closed form
    Tb_inv = np.array([[1 / s, 0, -Tb[0, 2] / s], [0, 1 / s, -Tb[1, 2] / s], [0, 0, 1.0]])
    H = Tb_inv @ Hn @ Ta
    return H / H[2, 2]


def closed_form_intrinsics(homographies, size) -> np.ndarray:
    """Zhang's closed form with zero skew: K (3,3) from >= 2 homographies.

    Works in pixel coordinates scaled by the image size (conditioning). Raises InitError when the
    homographies do not determine the image of the absolute conic (fronto-parallel views) or
    the solution is not a valid camera.
    """
    w, h = size
    s = float(max(w, h))
    N = np.array([[1 / s, 0, -w / (2 * s)], [0, 1 / s, -h / (2 * s)], [0, 0, 1]])
    rows = []
    for H in homographies:
        Hs = N @ H
        Hs = Hs / np.linalg.norm(Hs)
        h1, h2 = Hs[:, 0], Hs[:, 1]

        def v(a, b):  # b = (B11, B22, B13, B23, B33), B12 = 0 (zero skew)
            return np.array([a[0] * b[0], a[1] * b[1], a[0] * b[2] + a[2] * b[0],
                             a[1] * b[2] + a[2] * b[1], a[2] * b[2]])
        rows.append(v(h1, h2))
        rows.append(v(h1, h1) - v(h2, h2))
    V = np.asarray(rows)
    _, sv, vt = np.linalg.svd(V)
    # the null vector must be unique: the second smallest singular value must stand clear of 0
    if len(sv) < 5 or sv[-2] < 1e-6 * sv[0]:
        raise InitError("the board views do not determine the focal lengths (Zhang's equations are "
                        "degenerate): tilt the board (> 10 degrees) in at least two directions, "
                        "or add views")
    b = vt[-1]
    if b[0] < 0:
        b = -b
    B11, B22, B13, B23, B33 = b
    if B11 <= 0 or B22 <= 0:
        raise InitError("Zhang's closed form gave no valid camera (the views are nearly "
                        "fronto-parallel or the observations inconsistent)")
    cx = -B13 / B11
    cy = -B23 / B22
    lam = B33 - B13 * cx - B23 * cy
    if lam <= 0:
        raise InitError("Zhang's closed form gave no valid camera (negative scale): views nearly "
                        "fronto-parallel or observations inconsistent")
    fx = np.sqrt(lam / B11)
    fy = np.sqrt(lam / B22)
    Ks = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    return np.linalg.inv(N) @ Ks


def tilt_degrees(rvec) -> float:
    """Angle between the board normal and the device's optical axis, degrees."""
    import cv2
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))
    return float(np.degrees(np.arccos(min(1.0, abs(R[2, 2])))))


def init_device(points_board, q, size, *, n_distortion: int = 5, refine: bool = True,
                label: str = "device") -> DeviceSeed:
    """Initial intrinsics and per-view poses of one device.

    ARGUMENTS
    - points_board: list of (N_i, 3) board points (mm, z = 0), one per view.
    - q: list of (N_i, 2) observed pixels (finite rows only).
    - size: (W, H) pixels.
    - n_distortion: distortion terms for the OpenCV refinement (0, 4, 5, 8, 12).
    - refine: run ``cv2.calibrateCamera`` from the closed-form seed.

    RETURNED VALUE: DeviceSeed. Raises InitError for degenerate or insufficient views.
    """
    import cv2

    if len(points_board) < MIN_VIEWS:
        raise InitError(f"{label}: {len(points_board)} usable view(s); at least {MIN_VIEWS} board views "
                        "in different orientations are needed to determine fx, fy, cx, cy")
    for i, (X, x) in enumerate(zip(points_board, q)):
        if len(X) < 6:
            raise InitError(f"{label}: view {i + 1} has {len(X)} points; at least 6 are needed")
        if np.any(np.abs(X[:, 2]) > 1e-9 * max(1.0, np.abs(X).max())):
            raise InitError(f"{label}: view {i + 1}: board points must have z = 0 (planar board)")
    Hs = [homography(X[:, :2], x) for X, x in zip(points_board, q)]
    K = closed_form_intrinsics(Hs, size)
    dist = np.zeros(n_distortion)
    rvecs, tvecs = [], []
    for X, x in zip(points_board, q):
        ok, rv, tv = cv2.solvePnP(X.astype(np.float64), x.astype(np.float64), K, None,
                                  flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            raise InitError(f"{label}: solvePnP failed on a view")
        rvecs.append(rv.ravel())
        tvecs.append(tv.ravel())
    tilts = np.array([tilt_degrees(r) for r in rvecs])
    if tilts.max() < 3.0:
        raise InitError(f"{label}: all {len(tilts)} views are fronto-parallel (largest tilt "
                        f"{tilts.max():.2f} degrees): focal length and distance cannot be told apart. "
                        "Tilt the board by 10-40 degrees in several directions")
    method = "zhang-closed-form(fx,fy,cx,cy separately)+solvePnP"
    if refine:
        flags = cv2.CALIB_USE_INTRINSIC_GUESS
        if n_distortion == 0:
            flags |= (cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST)
            d0 = np.zeros(5)
        else:
            # k1 k2 p1 p2 only: higher terms are left to the bundle adjustment, which starts them
            # at 0 (freeing k3 here lets a few views run it to thousands, a poor seed)
            flags |= cv2.CALIB_FIX_K3
            d0 = np.zeros(5)
        try:
            rms, K2, d2, rv2, tv2 = cv2.calibrateCamera(
                [X.astype(np.float32) for X in points_board], [x.astype(np.float32) for x in q],
                tuple(int(v) for v in size), K.copy(), d0, flags=flags,
                criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12))
            ok = np.all(np.isfinite(K2)) and K2[0, 0] > 0 and K2[1, 1] > 0
        except cv2.error:
            ok = False
        if ok:
            K, rvecs, tvecs = K2, [r.ravel() for r in rv2], [t.ravel() for t in tv2]
            dist = np.zeros(n_distortion)
            if n_distortion:
                dist[:4] = np.asarray(d2, dtype=np.float64).ravel()[:4]
            method += "+cv2.calibrateCamera(guess)"
    res = []
    for X, x, rv, tv in zip(points_board, q, rvecs, tvecs):
        pr, _ = cv2.projectPoints(X.astype(np.float64), rv, tv, K, dist if dist.size else None)
        res.append(pr.reshape(-1, 2) - x)
    rms = float(np.sqrt(np.mean(np.concatenate(res) ** 2)))
    return DeviceSeed(np.asarray(K, float), np.asarray(dist, float), np.asarray(rvecs, float),
                      np.asarray(tvecs, float), rms, tilts, method)
