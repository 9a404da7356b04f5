"""Checkerboards (OpenCV's SB detector, fallback: classic detector + cornerSubPix) and ChArUco
boards (opencv-contrib's ``cv2.aruco.CharucoDetector``), with their corners mapped to our ids.

Our ids: ``row * cols + col`` with row 0 the BOTTOM row seen from the printed face (board +y up,
DESIGN.md). OpenCV lists a checkerboard's corners row by row in an orientation of its own
choosing; of the grid symmetries that could relabel them, only those whose board (x, y) -> image
map has a negative Jacobian determinant are proper (board seen from the front, image y down).
The remaining 180-degree turn (and 90-degree turns of a square grid) is decided:

- by the square colours when ``rows + cols`` is odd (the turn swaps colours). Convention (synth's
  boards): the square at the board's bottom-left corner, below-left of corner 0, is black, so an
  inner square (i, j) (between corner rows i, i+1 and columns j, j+1) is black when i + j is even;
- otherwise by convention: the board's +y axis points up in the image. ``notes`` says which.

A checkerboard is mirror-symmetric, so a mirrored image cannot be told from a turned board.
Partial checkerboards cannot be identified (use circles with markers, or ChArUco).
ChArUco ids come from the markers (partial views keep their identities); OpenCV's corner
``k = r * (cols) + c`` counts rows from the top of the printed board, so ours is
``(rows - 1 - r) * cols + c``.
"""
from __future__ import annotations

import cv2
import numpy as np
from scipy.ndimage import map_coordinates

from ..zhang import homography
from .result import BoardDetection, DetectionError, apply_homography, size_text, to_uint8


def _jacobian_det(H, xy):
    """det of d(image)/d(board xy) of homography H at board point xy (2,)."""
    e = 1e-3
    p = apply_homography(H, np.array([xy, xy + [e, 0], xy + [0, e]]))
    J = np.stack([p[1] - p[0], p[2] - p[0]], axis=1) / e
    return float(np.linalg.det(J))


def _grid_relabellings(rows, cols):
    """Index maps (rows, cols) -> position in OpenCV's row-major list, one per grid symmetry."""
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    maps = {"identity": r * cols + c, "turn 180": (rows - 1 - r) * cols + (cols - 1 - c),
            "flip rows": (rows - 1 - r) * cols + c, "flip cols": r * cols + (cols - 1 - c)}
    if rows == cols:
        n = rows
        maps.update({"transpose": c * n + r, "turn 90": c * n + (n - 1 - r),
                     "turn 270": (n - 1 - c) * n + r, "anti-transpose": (n - 1 - c) * n + (n - 1 - r)})
    return maps


def _colour_score(f, H, board):
    """Mean of (black-convention squares) minus mean of (white) sampled at inner square centres;
    negative when the colours agree with the convention (black where i + j is even)."""
    i, j = np.meshgrid(np.arange(board.rows - 1), np.arange(board.cols - 1), indexing="ij")
    s = board.spacing_mm
    xy = np.c_[((j + 0.5) - (board.cols - 1) / 2).ravel() * s, ((i + 0.5) - (board.rows - 1) / 2).ravel() * s]
    q = apply_homography(H, xy)
    v = map_coordinates(f, [q[:, 1], q[:, 0]], order=1, mode="nearest")
    even = ((i + j) % 2 == 0).ravel()
    return float(v[even].mean() - v[~even].mean()), float(np.std(v))


def _feature_px_grid(q_grid):
    """Half the mean distance to the grid neighbours, (rows, cols, 2) -> (rows*cols,)."""
    rows, cols, _ = q_grid.shape
    tot = np.zeros((rows, cols))
    cnt = np.zeros((rows, cols))
    for axis in (0, 1):
        d = np.linalg.norm(np.diff(q_grid, axis=axis), axis=-1)
        sl = [slice(None)] * 2
        sl[axis] = slice(0, -1)
        tot[tuple(sl)] += d
        cnt[tuple(sl)] += 1
        sl[axis] = slice(1, None)
        tot[tuple(sl)] += d
        cnt[tuple(sl)] += 1
    return (tot / np.maximum(cnt, 1) / 2).ravel()


def _find_corners(img8, board):
    size = (board.cols, board.rows)
    tries = [("findChessboardCornersSB (exhaustive, accuracy)",
              cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY),
             ("findChessboardCornersSB", cv2.CALIB_CB_NORMALIZE_IMAGE)]
    for name, flags in tries:
        ok, corners = cv2.findChessboardCornersSB(img8, size, flags=flags)
        if ok:
            return _subpix(img8, corners, board), name + " + cornerSubPix"
    ok, corners = cv2.findChessboardCorners(img8, size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if ok:
        return _subpix(img8, corners, board), "findChessboardCorners + cornerSubPix"
    return None, None


def _subpix(img8, corners, board):
    """cornerSubPix with a half-window of a fifth of the local corner spacing (3..11 px).
    On synth's rendered boards this brings the SB detector's 0.2-0.36 px RMS to ~0.08 px."""
    c = corners.reshape(-1, 2)
    spacing = np.median(np.linalg.norm(np.diff(c.reshape(board.rows, board.cols, 2), axis=1), axis=-1))
    win = int(np.clip(round(spacing / 5), 3, 11))
    out = cv2.cornerSubPix(img8, corners.reshape(-1, 1, 2).astype(np.float32), (win, win), (-1, -1),
                           (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-5))
    out = out.reshape(-1, 2).astype(np.float64)
    # keep the refinement only where it stayed near the detector's corner
    moved = np.linalg.norm(out - c, axis=1) > 0.25 * spacing
    out[moved] = c[moved]
    return out


def detect_checkerboard(f: np.ndarray, board, *, min_points: int = 6) -> BoardDetection:
    """Checkerboard inner corners in a float grey image (see the module docstring)."""
    where = f"checkerboard {board.rows}x{board.cols} (inner corners) in a {size_text(f)} image"
    if board.n_points < min_points:
        raise DetectionError(f"{where}: the board has {board.n_points} corners, fewer than min_points={min_points}")
    img8 = to_uint8(f)
    corners, how = _find_corners(img8, board)
    if corners is None:
        # a local contrast stretch helps dim, unevenly lit boards
        clahe = cv2.createCLAHE(clipLimit=3.0, tileGridSize=(8, 8)).apply(img8)
        corners, how = _find_corners(clahe, board)
        if corners is not None:
            how += " on a CLAHE-equalised image"
    if corners is None:
        raise DetectionError(f"{where}: board not found (OpenCV's SB and classic detectors failed; a "
                             f"checkerboard must be fully in view with all {board.n_points} corners)")
    pts = board.points_board()
    cands = []
    for name, m in _grid_relabellings(board.rows, board.cols).items():
        q = corners[m.ravel()]
        H = homography(pts[:, :2], q)
        if _jacobian_det(H, np.zeros(2)) < 0:
            cands.append((name, q, H))
    notes = []
    if (board.rows + board.cols) % 2 == 1:
        scored = sorted(((_colour_score(f, H, board)[0], name, q, H) for name, q, H in cands), key=lambda t: t[0])
        agree = [t[1:] for t in scored if t[0] < 0]
        if agree:
            cands = agree
            notes.append("orientation from the square colours (black square at the board's bottom-left corner)")
        else:
            notes.append("square colours do not match the convention (black bottom-left square) in any "
                         "proper orientation: orientation by the up convention")
    if len(cands) > 1:
        ups = [(apply_homography(H, [[0, 0], [0, board.spacing_mm]]), name, q, H) for name, q, H in cands]
        ups.sort(key=lambda t: t[0][1, 1] - t[0][0, 1])
        cands = [ups[0][1:]]
        notes.append("180-degree turn not visible in a checkerboard with rows + cols even: resolved by "
                     "convention (board +y points up in the image)")
    name, q, H = cands[0]
    q_grid = q.reshape(board.rows, board.cols, 2)
    ids = np.arange(board.n_points, dtype=np.int64)
    return BoardDetection(ids=ids, q=q, points_board=pts, feature_px=_feature_px_grid(q_grid),
                          homography=homography(pts[:, :2], q), method=f"checkerboard: {how}",
                          notes=notes, image_size=(f.shape[1], f.shape[0]))


def _charuco_board(board):
    marker = board.extra.get("marker_mm", board.extra.get("marker_size_mm"))
    if marker is None or not isinstance(marker, (int, float)) or not 0 < marker < board.spacing_mm:
        raise DetectionError(f"charuco board: [board] needs marker_mm, the ArUco marker side in mm, "
                             f"0 < marker_mm < spacing_mm ({board.spacing_mm}); got {marker!r}")
    name = board.aruco_dictionary
    if not hasattr(cv2.aruco, name):
        raise DetectionError(f"charuco board: unknown aruco_dictionary {name!r} (e.g. DICT_5X5_1000)")
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
    cb = cv2.aruco.CharucoBoard((board.cols + 1, board.rows + 1), float(board.spacing_mm), float(marker), dictionary)
    if board.extra.get("legacy_pattern", False):
        cb.setLegacyPattern(True)
    return cb


def detect_charuco(f: np.ndarray, board, *, min_points: int = 6) -> BoardDetection:
    """ChArUco inner corners with ids from the ArUco markers (see the module docstring)."""
    where = f"charuco board {board.rows}x{board.cols} (inner corners) in a {size_text(f)} image"
    cb = _charuco_board(board)
    img8 = to_uint8(f)
    detector = cv2.aruco.CharucoDetector(cb)
    ch_corners, ch_ids, mk_corners, mk_ids = detector.detectBoard(img8)
    n_markers = 0 if mk_ids is None else len(mk_ids)
    if ch_ids is None or len(ch_ids) == 0:
        raise DetectionError(f"{where}: no ChArUco corner found ({n_markers} ArUco markers of "
                             f"{board.aruco_dictionary} detected)")
    cv_ids = ch_ids.ravel().astype(np.int64)
    q = ch_corners.reshape(-1, 2).astype(np.float64)
    # the interpolated corners sit ~0.5 px off the pixel-centre convention on rendered boards;
    # a saddle-point refinement (cornerSubPix, half-window a fifth of the local spacing) fixes it
    if len(q) >= 2:
        from scipy.spatial import cKDTree
        dist, _ = cKDTree(q).query(q, k=2)
        spacing = float(np.median(dist[:, 1]))
        win = int(np.clip(round(spacing / 5), 3, 11))
        ref = cv2.cornerSubPix(img8, q.astype(np.float32).reshape(-1, 1, 2), (win, win), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-5)).reshape(-1, 2)
        keep = np.linalg.norm(ref - q, axis=1) < 0.25 * spacing
        q[keep] = ref[keep]
    r_cv, c = cv_ids // board.cols, cv_ids % board.cols
    ids = (board.rows - 1 - r_cv) * board.cols + c
    order = np.argsort(ids)
    ids, q = ids[order], q[order]
    if len(ids) < max(min_points, 4):
        raise DetectionError(f"{where}: {len(ids)} ChArUco corners identified, fewer than min_points={min_points}")
    pts = board.points_board(ids)
    H = homography(pts[:, :2], q)
    # feature size: half the local spacing from the homography
    step = apply_homography(H, np.c_[pts[:, 0] + board.spacing_mm, pts[:, 1]]) - q
    feature = np.linalg.norm(step, axis=1) / 2
    notes = [f"{n_markers} ArUco markers, {len(ids)} of {board.n_points} corners"]
    return BoardDetection(ids=ids, q=q, points_board=pts, feature_px=feature, homography=H,
                          method="charuco: cv2.aruco.CharucoDetector + cornerSubPix", notes=notes,
                          image_size=(f.shape[1], f.shape[0]))
