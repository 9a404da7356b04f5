"""Circle grids with large orientation markers: candidates -> lattice -> identities -> centres.

Identities come from the large markers: every lattice-to-board map that is a symmetry of the
square grid (8 of them) plus an offset is scored by how the large/small blobs agree with
``board.large_markers``; a map must keep every lattice blob on the board. The map must also be
*proper*: seen from the printed face, board (x right, y up) -> image (x right, y down) has a
negative Jacobian determinant, whatever the camera. A mirrored image therefore reads as an
improper map and is refused; when a proper and an improper map fit equally well (a partial view
of a marker layout with a mirror symmetry) the view is refused as ambiguous.

Perspective bias: a circle of radius r at board point c images to the conic
``C_img = H^-T C H^-1``; its centre is not ``H c``. With a local homography H (fitted to the
neighbouring circles) the bias ``centre(C_img) - H c`` is subtracted from the measured ellipse
centre.

Lens bias: through a distorted lens the image of the circle is no longer a conic, and the local
pixel homography only follows the distortion to first order. Given a camera model (``camera=``,
e.g. a first calibration's), :func:`lens_centre_bias` images each circle's boundary exactly
(local homography board -> *undistorted* normalised coordinates, fitted to the undistorted
centres, then the lens and K), measures it as the detector does (ellipse through the boundary on
48 rays of uniform image angle, or the area centroid for ``"moments"``) and subtracts its offset
from the distorted image of the centre. Measured (``docs/calib.md``): on the paper's system the
pixel-homography correction leaves <= 1.1e-4 px (the lens term is negligible there); a close
camera (f 1000 px, 400 mm, 8/14 mm circles) with k1 = -0.3, k2 = 0.1 is left with up to 0.018 px
(RMS 0.006 px), which the lens-aware correction removes.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..distortion import distort, undistort
from ..zhang import homography
from .blobs import find_blobs, fit_ellipse_direct
from .lattice import grow_lattice
from .result import BoardDetection, DetectionError, apply_homography, size_text

#: the 8 symmetries of the square grid acting on lattice cells (i, j) -> (row, col)
GRID_SYMMETRIES = [np.array(m) for m in ([[1, 0], [0, 1]], [[0, -1], [1, 0]], [[-1, 0], [0, -1]], [[0, 1], [-1, 0]],
                                          [[-1, 0], [0, 1]], [[1, 0], [0, -1]], [[0, 1], [1, 0]], [[0, -1], [-1, 0]])]


def circle_image_centre(H, centre_xy, radius):
    """Centre (N, 2) px of the image conic of circles (board centres (N, 2) mm, radius mm) under
    the board -> image homography H (3, 3) (or (N, 3, 3), one per circle)."""
    centre_xy = np.atleast_2d(np.asarray(centre_xy, dtype=np.float64))
    Hs = np.broadcast_to(np.asarray(H, dtype=np.float64), (len(centre_xy), 3, 3))
    r = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(centre_xy),))
    out = np.empty((len(centre_xy), 2))
    for k, ((cx, cy), Hk, rk) in enumerate(zip(centre_xy, Hs, r)):
        C = np.array([[1.0, 0.0, -cx], [0.0, 1.0, -cy], [-cx, -cy, cx * cx + cy * cy - rk * rk]])
        Hi = np.linalg.inv(Hk)
        Ci = Hi.T @ C @ Hi
        out[k] = np.linalg.solve(Ci[:2, :2], -Ci[:2, 2])
    return out


def perspective_bias(H, centre_xy, radius):
    """(N, 2) px: image-conic centre minus the image of the circle centre (see module doc)."""
    centre_xy = np.atleast_2d(np.asarray(centre_xy, dtype=np.float64))
    Hs = np.broadcast_to(np.asarray(H, dtype=np.float64), (len(centre_xy), 3, 3))
    proj = np.array([apply_homography(Hk, c[None])[0] for Hk, c in zip(Hs, centre_xy)])
    return circle_image_centre(Hs, centre_xy, radius) - proj


def _ray_boundary(ring, centre, n_rays):
    """(n_rays, 2): points of the closed boundary ``ring`` (M, 2) px, star-shaped about
    ``centre`` (2,), at ``n_rays`` uniform image angles from ``centre`` (as the edge detector
    samples it), by linear interpolation in angle."""
    d = ring - centre
    ang = np.arctan2(d[:, 1], d[:, 0])
    order = np.argsort(ang)
    ang, pts = ang[order], ring[order]
    ang = np.r_[ang[-1] - 2 * np.pi, ang, ang[0] + 2 * np.pi]
    pts = np.r_[pts[-1:], pts, pts[:1]]
    th = np.linspace(-np.pi, np.pi, n_rays, endpoint=False)
    return np.c_[np.interp(th, ang, pts[:, 0]), np.interp(th, ang, pts[:, 1])]


def _area_centroid(poly):
    """Centroid (2,) of the region inside the closed polygon ``poly`` (M, 2) (shoelace)."""
    x, y = poly[:, 0], poly[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    a = cross.sum() / 2
    return np.array([((x + xn) * cross).sum(), ((y + yn) * cross).sum()]) / (6 * a)


def lens_centre_bias(camera, H_norm, centre_xy, radius, *, centre_method: str = "edge", n_rays: int = 48,
                     n_boundary: int = 1440):
    """(N, 2) px: where the detector finds the centre of an imaged circle minus the image of its
    centre, through the full lens model of ``camera`` (a ``calib.device.DeviceModel``: K with
    skew, OpenCV distortion).

    ARGUMENTS
    - H_norm: (3, 3) or (N, 3, 3) board (mm) -> undistorted normalised camera coordinates (the
      exact map of the board plane, pose included).
    - centre_xy: (N, 2) circle centres on the board, mm; radius: scalar or (N,), mm.
    - centre_method: "edge" (ellipse through the boundary at ``n_rays`` uniform image angles,
      as ``blobs.find_blobs``) or "moments" (centroid of the imaged disc).
    - n_boundary: boundary samples per circle before the angular resampling.

    Without distortion this equals :func:`perspective_bias` of the pixel homography
    ``K @ H_norm`` (the ellipse through the exact conic's points is that conic).
    """
    centre_xy = np.atleast_2d(np.asarray(centre_xy, dtype=np.float64))
    n = len(centre_xy)
    Hs = np.broadcast_to(np.asarray(H_norm, dtype=np.float64), (n, 3, 3))
    r = np.broadcast_to(np.asarray(radius, dtype=np.float64), (n,))
    th = np.linspace(0, 2 * np.pi, n_boundary, endpoint=False)
    ring = centre_xy[:, None, :] + r[:, None, None] * np.stack([np.cos(th), np.sin(th)], -1)[None]
    pts = np.concatenate([centre_xy[:, None, :], ring], axis=1)            # (N, 1 + M, 2)
    hom = np.einsum("nij,nmj->nmi", Hs, np.concatenate([pts, np.ones(pts.shape[:2] + (1,))], -1))
    q = camera.normalized_to_pixels(distort(hom[..., :2] / hom[..., 2:], camera.distortion))
    out = np.empty((n, 2))
    for k in range(n):
        c_img, boundary = q[k, 0], q[k, 1:]
        if centre_method == "moments":
            found = _area_centroid(boundary)
        else:
            fit = fit_ellipse_direct(*_ray_boundary(boundary, c_img, n_rays).T)
            found = fit[0] if fit is not None else c_img
        out[k] = found - c_img
    return out


def _corrected_centres(q_ellipse, rc, pts, radius, camera, centre_method, rounds: int = 2):
    """Measured centres minus the centre bias (module docstring), ``rounds`` times re-fitting
    the local homographies to the corrected centres. Returns (q (N, 2), bias (N, 2), how)."""
    q = q_ellipse.copy()
    for _ in range(rounds):
        if camera is None:
            Hl = _local_homographies(rc, pts, q, homography(pts, q))
            bias = perspective_bias(Hl, pts, radius)
        else:
            xy, ok = undistort(camera.pixels_to_normalized(q), camera.distortion)
            if not ok.all():
                raise DetectionError(f"{int((~ok).sum())} circle centre(s) lie where the camera's lens model "
                                     "cannot be inverted; the lens bias cannot be corrected there")
            Hl = _local_homographies(rc, pts, xy, homography(pts, xy))
            bias = lens_centre_bias(camera, Hl, pts, radius, centre_method=centre_method)
        q = q_ellipse - bias
    return q, bias, "perspective" if camera is None else "perspective + lens"


def _classify_large(blobs, board):
    """(M,) bool: blobs clearly bigger than the median of their 8 nearest neighbours."""
    if not board.large_markers:
        return np.zeros(len(blobs), bool)
    area = blobs.axes[:, 0] * blobs.axes[:, 1]
    k = min(9, len(blobs))
    _, idx = cKDTree(blobs.xy).query(blobs.xy, k=k)
    local = np.median(area[idx[:, 1:]], axis=1)
    ratio_expected = (board.large_diameter_mm / board.small_diameter_mm) ** 2
    return area > np.sqrt(ratio_expected) * local


def _placements(cells, is_large, board, jac_sign):
    """Every placement of the lattice on the board that keeps all its blobs on the board.

    Yields dicts: rc (M, 2) board (row, col) per blob, conflicts (large/small disagreements with
    ``board.large_markers``), hits (large blobs on large cells), proper (seen from the front)."""
    rows, cols = board.rows, board.cols
    large_map = np.zeros((rows, cols), bool)
    for r, c in board.large_markers:
        large_map[r, c] = True
    markers = np.array(board.large_markers, dtype=int).reshape(-1, 2)
    for G in GRID_SYMMETRIES:
        rc0 = cells @ G.T
        proper = jac_sign * np.sign(np.linalg.det(G)) > 0
        if len(markers):
            offsets = {tuple(m - rc0[i]) for i in np.nonzero(is_large)[0] for m in markers}
        else:
            offsets = {tuple(-rc0.min(axis=0))}
        for o in offsets:
            rc = rc0 + np.array(o)
            if not ((rc[:, 0] >= 0) & (rc[:, 0] < rows) & (rc[:, 1] >= 0) & (rc[:, 1] < cols)).all():
                continue
            expect = large_map[rc[:, 0], rc[:, 1]]
            yield {"rc": rc, "conflicts": int(np.sum(expect != is_large)), "hits": int(np.sum(expect & is_large)),
                   "proper": bool(proper)}


def _identify(cells, is_large, board, jac_sign, where):
    """Pick the lattice -> (row, col) placement (module docstring). Returns (placements, text):
    one placement, or for a board without markers the proper full-board placements (the caller
    decides between them by convention)."""
    places = list(_placements(cells, is_large, board, jac_sign))
    if not places:
        raise DetectionError(f"{where}: no placement of the {len(cells)} grid circles on the {board.rows}x"
                             f"{board.cols} board fits (lattice larger than the board, or stray blobs on it)")
    if not board.large_markers:
        full = [p for p in places if p["proper"]] if len(cells) == board.n_points else []
        if not full:
            raise DetectionError(f"{where}: a board without large markers must be fully in view: found "
                                 f"{len(cells)} of {board.n_points} circles on the grid")
        return full, "no large markers: all circles in view"
    allowed = 1 if int(is_large.sum()) >= 4 else 0   # one misread size is tolerated with >= 4 markers
    good = [p for p in places if p["conflicts"] <= allowed and p["hits"] > 0]
    n_large = int(is_large.sum())
    if not good:
        best = min(p["conflicts"] for p in places)
        raise DetectionError(f"{where}: the large circles ({n_large} found) do not match the board's "
                             f"large_markers {list(board.large_markers)} in any orientation "
                             f"(best placement: {best} size conflicts)")
    key = lambda p: (p["conflicts"], -p["hits"])  # noqa: E731
    proper = [p for p in good if p["proper"]]
    if not proper:
        raise DetectionError(f"{where}: the large markers read as the board's MIRROR image (the image is "
                             f"flipped, or the board is seen through its back); refusing to order it")
    best = min(key(p) for p in proper)
    winners = [p for p in proper if key(p) == best]
    if any(key(p) <= best for p in good if not p["proper"]):
        raise DetectionError(f"{where}: ambiguous orientation: the visible large markers fit the board and its "
                             f"mirror image equally well ({n_large} large circles, {len(cells)} grid circles; "
                             f"the marker layout is mirror-symmetric and the view too partial to tell); "
                             f"refusing rather than guessing: bring a full row or column of the board into view")
    if len(winners) > 1:
        raise DetectionError(f"{where}: ambiguous orientation: {len(winners)} placements of the {n_large} "
                             f"visible large markers fit equally well")
    p = winners[0]
    return winners, (f"{p['hits']} of {len(board.large_markers)} large markers matched, "
                     f"{p['conflicts']} size conflicts")


def _fit_rc_map(cells, xy):
    """Sign of det of the affine (i, j) -> image map (handedness of the grown lattice)."""
    A = np.c_[cells.astype(float), np.ones(len(cells))]
    coef = np.linalg.lstsq(A, xy, rcond=None)[0]
    return float(np.sign(np.linalg.det(coef[:2].T)))


def _up_convention(H, board):
    """True when the board's +y axis points up (negative image y) at the board centre."""
    p0 = apply_homography(H, [[0.0, 0.0], [0.0, board.spacing_mm]])
    return p0[1, 1] < p0[0, 1]


def _local_homographies(ids_rc, xy_board, q, H_global):
    """One board->image homography per feature, fitted to the features within 2 cells of it
    (at least 8), else the global one."""
    Hs = np.empty((len(q), 3, 3))
    for k, rc in enumerate(ids_rc):
        near = np.max(np.abs(ids_rc - rc), axis=1) <= 2
        if near.sum() < 8:
            near = np.max(np.abs(ids_rc - rc), axis=1) <= 3
        Hs[k] = homography(xy_board[near], q[near]) if near.sum() >= 8 else H_global
    return Hs


def _grid_circles(blobs, min_points: int, where: str):
    """The complete circle candidates that lie on one grown lattice: (blob indices (M,), lattice
    cells (M, 2) counted from 0). DetectionError when too few are found."""
    whole = ~blobs.cut
    if whole.sum() < max(min_points, 5):
        raise DetectionError(f"{where}: found {int(whole.sum())} complete circle candidates "
                             f"(need at least {max(min_points, 5)}: min_points={min_points}, and 5 to find a grid); "
                             f"no board in view?")
    xy = blobs.xy[whole]
    sub = np.nonzero(whole)[0]
    grown = grow_lattice(xy)
    if grown is None:
        raise DetectionError(f"{where}: {len(xy)} circle candidates but no regular grid among them")
    cells, assigned, _ = grown
    if assigned.sum() < max(min_points, 5):
        raise DetectionError(f"{where}: only {int(assigned.sum())} candidates lie on a common grid "
                             f"(need at least {max(min_points, 5)})")
    cells = cells[assigned]
    return sub[assigned], cells - cells.min(axis=0)


def _second_pass(board, blobs, ids, idx, Hg, image_size, notes):
    """Circles the lattice growth missed, found where the board homography ``Hg`` predicts them;
    circles cut by the image edge are dropped. Returns (ids, blob indices); ``notes`` says what
    was added, dropped and outside the image."""
    W_img, H_img = image_size
    missing = np.setdiff1d(np.arange(board.n_points), ids)
    if not missing.size:
        return ids, idx
    pred = apply_homography(Hg, board.points_board(missing)[:, :2])
    tree = cKDTree(blobs.xy)
    d, k = tree.query(pred)
    spacing = np.median(np.linalg.norm(np.diff(apply_homography(
        Hg, np.array([[0, 0], [board.spacing_mm, 0], [0, board.spacing_mm]])), axis=0), axis=1))
    near = d < 0.25 * spacing
    used = set(idx.tolist())
    add_ids, add_idx, cut_ids = [], [], []
    for m, ok, kk in zip(missing, near, k):
        if not ok or kk in used:
            continue
        if blobs.cut[kk]:
            cut_ids.append(int(m))
        else:
            add_ids.append(int(m))
            add_idx.append(int(kk))
            used.add(int(kk))
    if add_ids:
        ids = np.r_[ids, add_ids]
        idx = np.r_[idx, add_idx]
        notes.append(f"{len(add_ids)} circles added from the board homography (off the grown lattice)")
    if cut_ids:
        notes.append(f"dropped {len(cut_ids)} circles cut by the image edge or the unlit region: ids {cut_ids}")
    outside = [int(m) for m, p in zip(missing, pred) if not (0 <= p[0] <= W_img - 1 and 0 <= p[1] <= H_img - 1)]
    if outside:
        notes.append(f"{len(outside)} circles outside the image (partial board)")
    return ids, idx


def detect_circles(f: np.ndarray, board, *, min_points: int = 6, centre_method: str = "edge",
                   correct_bias: bool = True, camera=None) -> BoardDetection:
    """Circle-grid detection on a float grey image ``f`` (H, W); see the module docstring.
    ``camera``: a ``calib.device.DeviceModel`` of the camera (e.g. a first calibration): the
    centre bias is then corrected through its lens model (lens + perspective), else with local
    pixel homographies (perspective only)."""
    H_img, W_img = f.shape
    where = f"circle board {board.rows}x{board.cols} in a {size_text(f)} image"
    if camera is not None and tuple(getattr(camera, "size", ())) != (W_img, H_img):
        raise DetectionError(f"{where}: the camera model given for the lens-bias correction is for "
                             f"{getattr(camera, 'size', '?')} px images, not {W_img}x{H_img}")
    notes = []
    blobs = find_blobs(f, board.polarity == "dark-on-light", method=centre_method)
    notes += blobs.notes
    idx, cells = _grid_circles(blobs, min_points, where)
    large_all = _classify_large(blobs, board)
    is_large = large_all[idx]
    if board.large_markers and not is_large.any():
        raise DetectionError(f"{where}: none of the {len(idx)} grid circles is a large orientation marker; "
                             f"the board's identity cannot be read")
    jac = _fit_rc_map(cells, blobs.xy[idx])
    choice, how = _identify(cells, is_large, board, jac, where)
    if len(choice) > 1:
        # no markers: the 180-degree turn is invisible; convention: board +y points up in the image
        def down(p):
            ids_p = p["rc"][:, 0] * board.cols + p["rc"][:, 1]
            return not _up_convention(homography(board.points_board(ids_p)[:, :2], blobs.xy[idx]), board)
        choice = sorted(choice, key=down)
        notes.append("board without large markers: 180-degree turn resolved by convention (board +y up in the image)")
    rc = choice[0]["rc"]
    notes.append(f"identification: {how}")
    ids = rc[:, 0] * board.cols + rc[:, 1]
    pts = board.points_board(ids)[:, :2]
    ids, idx = _second_pass(board, blobs, ids, idx, homography(pts, blobs.xy[idx]), (W_img, H_img), notes)
    order = np.argsort(ids)
    ids, idx = ids[order], idx[order]
    if len(ids) < min_points:
        raise DetectionError(f"{where}: {len(ids)} circles identified, fewer than min_points={min_points}")
    is_large_id = board.is_large()[ids]
    radius = np.where(is_large_id, (board.large_diameter_mm or 0) / 2, board.small_diameter_mm / 2)
    pts = board.points_board(ids)[:, :2]
    q = blobs.xy[idx].copy()
    rc = np.c_[ids // board.cols, ids % board.cols]
    method = f"circles: {centre_method} centres, lattice + large-marker identification"
    if correct_bias:
        q, bias, how = _corrected_centres(q, rc, pts, radius, camera, centre_method)
        mag = np.linalg.norm(bias, axis=1)
        notes.append(f"{how} bias corrected: mean {mag.mean():.4f} px, max {mag.max():.4f} px")
        method += f", {how} bias corrected"
    H = homography(pts, q)
    return BoardDetection(ids=ids.astype(np.int64), q=q, points_board=board.points_board(ids),
                          feature_px=blobs.size[idx].astype(np.float64), homography=H, method=method,
                          notes=notes, image_size=(W_img, H_img))
