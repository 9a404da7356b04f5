"""Circle-grid detection on rendered boards (synth): identities, sub-pixel centres against the true
projections, the perspective bias and its correction, and the hard cases (partial, mirrored,
turned, no board, low contrast, saturation, polarity)."""
from dataclasses import replace

import numpy as np
import pytest

from calib.board import Board, paper_board
from calib.detect import (BoardDetection, DetectionError, circle_image_centre, detect_board, lens_centre_bias,
                          perspective_bias)
from bench.detect_accuracy import centre_errors, close_system, render_white
from calib.detect.blobs import fit_ellipse_direct
from calib.system import default_system
from synth.scenes.poses import rotation_xyz_deg


@pytest.fixture(scope="session")
def renders(tmp_path_factory):
    """Small renders shared by the tests of this module (cached on disk for the session)."""
    cache = tmp_path_factory.mktemp("detect_renders")
    paper, big = paper_board(), paper_board(small_diameter_mm=8.0, large_diameter_mm=14.0)
    twin, close = default_system(), close_system()
    jobs = {"twin_10_20_noisy": (twin, paper, (10, 20), 1), "twin_0_0": (twin, paper, (0, 0), None),
            "close_big_40": (close, big, (40, 0), None),
            "close_no_markers": (close, paper_board(large_markers=()), (10, 20), 2)}
    out = {}
    for name, (system, spec, tilt, noise) in jobs.items():
        path = cache / f"{name}.npz"
        if path.exists():
            d = np.load(path)
            img, R = d["img"], d["R"]
        else:
            img, R = render_white(system, spec, tilt, noise)
            np.savez(path, img=img, R=R)
        out[name] = (img, R, system, spec)
    return out


def _truth(system, board, ids, R_wb):
    return system.camera.project(board.points_board(ids) @ R_wb.T)


def test_paper_twin_circles_identified_with_sub_0_1_px_centres(renders):
    img, R, system, spec = renders["twin_10_20_noisy"]
    board = spec
    det = detect_board(img, board)
    assert isinstance(det, BoardDetection)
    assert np.all(np.diff(det.ids) > 0) and det.ids.dtype == np.int64
    assert det.q.shape == (len(det), 2) and det.points_board.shape == (len(det), 3)
    np.testing.assert_allclose(det.points_board, board.points_board(det.ids))
    err = np.linalg.norm(det.q - _truth(system, board, det.ids, R), axis=1)
    assert len(det) >= 75          # 77 of 99 circles are complete in this view (rows 7-8 out of it)
    assert err.max() < 0.1, err.max()
    assert np.sqrt(np.mean(err ** 2)) < 0.04
    # feature size: small circles ~3 px, large ~7.5 px mean semi-axis at 850 mm
    large = board.is_large()[det.ids]
    assert 2.0 < np.median(det.feature_px[~large]) < 4.0 < 6.0 < np.median(det.feature_px[large]) < 9.0
    assert any("outside the image" in n for n in det.notes)
    assert det.reprojection_rms_px() < 1.5  # homography vs. a distorted lens: well under a pixel or so


def test_perspective_bias_is_the_conic_centre_offset_of_a_projected_circle():
    H = np.array([[900.0, 40.0, 320.0], [-30.0, -880.0, 240.0], [0.9, 0.4, 1.0]]) / 1.0
    H[2] = [0.0012, 0.0009, 1.0]
    c, r = np.array([12.0, -7.0]), 6.0
    th = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    ring = np.c_[c[0] + r * np.cos(th), c[1] + r * np.sin(th), np.ones_like(th)] @ H.T
    ring = ring[:, :2] / ring[:, 2:]
    centre, axes, _ = fit_ellipse_direct(ring[:, 0], ring[:, 1])
    np.testing.assert_allclose(circle_image_centre(H, c, r)[0], centre, atol=1e-7)
    img_c = H @ [c[0], c[1], 1.0]
    bias = perspective_bias(H, c, r)[0]
    np.testing.assert_allclose(bias, centre - img_c[:2] / img_c[2], atol=1e-7)
    assert np.linalg.norm(bias) > 0.05   # a strong perspective: a visible bias
    np.testing.assert_allclose(perspective_bias(H, c, 1e-6)[0], 0, atol=1e-9)  # vanishes with the radius


def test_perspective_bias_correction_removes_the_bias_on_a_close_tilted_board(renders):
    img, R, system, spec = renders["close_big_40"]
    e_raw, _ = centre_errors(img, system, spec, R, correct_bias=False)
    e_cor, det = centre_errors(img, system, spec, R, correct_bias=True)
    rms_raw = np.sqrt(np.mean(np.sum(e_raw ** 2, axis=1)))
    rms_cor = np.sqrt(np.mean(np.sum(e_cor ** 2, axis=1)))
    assert rms_raw > 0.05           # 8 / 14 mm circles at 40 deg, 400 mm: the bias is visible (0.065 px)
    assert rms_cor < 0.35 * rms_raw  # measured 0.016 px
    assert rms_cor < 0.03
    assert any("perspective bias corrected" in n for n in det.notes)


def _distorted_close(dist):
    from calib.system import SystemModel

    base = close_system()
    return SystemModel(base.camera.with_(distortion=dist), base.projector, {})


def _board_to_normalised(system, R_wb):
    """Board (mm) -> undistorted normalised camera coordinates of the board at R_wb, t = 0."""
    cam = system.camera
    R = cam.R @ R_wb
    return np.c_[R[:, :2], cam.t]


def test_lens_centre_bias_without_distortion_is_the_perspective_bias():
    system = close_system()
    H_norm = _board_to_normalised(system, rotation_xyz_deg([30.0, 20.0, 0.0]))
    K = system.camera.K
    c = np.array([[40.0, -60.0], [0.0, 0.0], [-80.0, 20.0]])
    expect = perspective_bias(K @ H_norm, c, 7.0)
    assert np.abs(expect).max() > 0.05          # a visible perspective bias
    np.testing.assert_allclose(lens_centre_bias(system.camera, H_norm, c, 7.0), expect, atol=1e-6)
    np.testing.assert_allclose(lens_centre_bias(system.camera, H_norm, c, 7.0, centre_method="moments"),
                               expect, atol=1e-6)


def test_lens_aware_correction_recovers_the_projected_centre_through_a_strong_lens():
    """Exact circle boundaries through a strongly distorted close camera (k1 -0.6): the edge
    detector's measurement (ellipse through the boundary on 48 rays from the disc's centroid) is
    off the distorted image of the centre by up to 0.16 px; the pixel-homography correction leaves
    a radial error of ~0.03 px at the image edge (the lens' curvature within a circle), the
    lens-aware one < 1e-3 px."""
    from calib.detect.circles import _area_centroid, _corrected_centres, _ray_boundary

    system = _distorted_close([-0.6, 0.3, 0.001, -0.001, 0.0])
    cam = system.camera
    board = paper_board(small_diameter_mm=8.0, large_diameter_mm=14.0)
    R_wb = rotation_xyz_deg([30.0, 30.0, 0.0])
    ids = np.arange(board.n_points)
    pts = board.points_board(ids)[:, :2]
    radius = np.where(board.is_large()[ids], 7.0, 4.0)
    th = np.linspace(0, 2 * np.pi, 4000, endpoint=False)
    measured = []
    for c, r in zip(pts, radius):
        ring = cam.project(np.c_[c[0] + r * np.cos(th), c[1] + r * np.sin(th), 0 * th] @ R_wb.T)
        edge = _ray_boundary(ring, _area_centroid(ring), 48)
        measured.append(fit_ellipse_direct(edge[:, 0], edge[:, 1])[0])
    measured = np.array(measured)
    true = cam.project(board.points_board(ids) @ R_wb.T)
    rc = np.c_[ids // board.cols, ids % board.cols]
    q_persp, _, _ = _corrected_centres(measured, rc, pts, radius, None, "edge")
    q_lens, _, how = _corrected_centres(measured, rc, pts, radius, cam, "edge")
    err = {k: np.linalg.norm(q - true, axis=1) for k, q in (("raw", measured), ("persp", q_persp), ("lens", q_lens))}
    assert how == "perspective + lens"
    assert err["raw"].max() > 0.1
    assert err["persp"].max() > 0.02                 # measured 0.034 px
    assert err["lens"].max() < 1e-3, err["lens"].max()


def test_lens_aware_detection_removes_the_radial_error_on_a_rendered_distorted_board():
    """Rendered white frames of the strongly distorted close camera: the mean radial error of the
    outer third of the circles is ~ -0.015 px with the pixel-homography correction (the lens
    pulls the measured centres inwards) and within +-0.005 px with the lens-aware correction."""
    system = _distorted_close([-0.6, 0.3, 0.001, -0.001, 0.0])
    cam = system.camera
    board = spec = paper_board(small_diameter_mm=8.0, large_diameter_mm=14.0)
    radial = {None: [], "lens": []}
    for tilt in [(20, 0), (30, 30)]:
        img, R = render_white(system, spec, tilt, None)
        for key, model in ((None, None), ("lens", cam)):
            det = detect_board(img, board, camera=model)
            true = _truth(system, board, det.ids, R)
            out = true - [cam.cx, cam.cy]
            rr = np.linalg.norm(out, axis=1)
            far = rr > np.quantile(rr, 2 / 3)
            radial[key].append(np.sum((det.q - true)[far] * out[far] / rr[far, None], axis=1))
    outer = {k: float(np.mean(np.concatenate(v))) for k, v in radial.items()}
    assert outer[None] < -0.008, outer                # measured -0.015 px
    assert abs(outer["lens"]) < 0.005, outer          # measured -0.0004 px
    with pytest.raises(DetectionError, match="camera model given .* for \\(800, 600\\) px images, not 640x480"):
        detect_board(img, board, camera=cam.with_(size=(800, 600)))


def test_partial_board_keeps_identities_and_drops_cut_circles(renders):
    img, R, system, spec = renders["twin_0_0"]
    board = spec
    col4 = _truth(system, board, [4 * board.cols + 3], R)[0, 0]
    x0 = int(round(col4))          # cuts through the circles of column 3
    det = detect_board(img[:, x0:], board)
    truth = _truth(system, board, det.ids, R) - [x0, 0]
    err = np.linalg.norm(det.q - truth, axis=1)
    assert err.max() < 0.1
    assert 30 <= len(det) < 77
    assert any("cut by the image edge" in n for n in det.notes)
    assert det.q[:, 0].min() > 2   # no cut circle kept


def test_board_turned_180_deg_in_the_image_keeps_its_identities(renders):
    img, R, system, spec = renders["twin_10_20_noisy"]
    board = spec
    H, W = img.shape
    det = detect_board(np.ascontiguousarray(img[::-1, ::-1]), board)
    truth = _truth(system, board, det.ids, R)
    truth = np.c_[W - 1 - truth[:, 0], H - 1 - truth[:, 1]]
    assert len(det) >= 75
    assert np.linalg.norm(det.q - truth, axis=1).max() < 0.1


def test_mirror_flipped_image_is_refused(renders):
    img, _, _, spec = renders["twin_10_20_noisy"]
    with pytest.raises(DetectionError, match="MIRROR|mirror"):
        detect_board(np.ascontiguousarray(img[:, ::-1]), spec)


def test_light_on_dark_board_and_low_contrast(renders):
    img, R, system, spec = renders["twin_10_20_noisy"]
    board = spec
    inv = replace(spec, polarity="light-on-dark")
    det = detect_board(255 - img, inv)
    assert len(det) >= 75
    det16 = detect_board(img.astype(np.uint16) * 257, board)      # 16-bit input, same answer
    det8 = detect_board(img, board)
    assert np.array_equal(det16.ids, det8.ids) and np.allclose(det16.q, det8.q, atol=1e-6)
    assert np.linalg.norm(det.q - _truth(system, board, det.ids, R), axis=1).max() < 0.15
    rng = np.random.default_rng(3)
    low = 100 + 0.12 * img.astype(float) + rng.normal(0, 0.5, img.shape)   # ink contrast ~20 grey levels
    det = detect_board(np.clip(np.round(low), 0, 255).astype(np.uint8), board)
    assert len(det) >= 75
    assert np.linalg.norm(det.q - _truth(system, board, det.ids, R), axis=1).max() < 0.3


def test_saturated_patch_loses_only_the_circles_under_it(renders):
    img, R, system, spec = renders["twin_10_20_noisy"]
    board = spec
    sat = img.copy()
    sat[300:420, 60:260] = 255
    det = detect_board(sat, board)
    truth = _truth(system, board, det.ids, R)
    assert np.linalg.norm(det.q - truth, axis=1).max() < 0.1
    assert 60 <= len(det) <= 74
    assert not np.any((det.q[:, 0] > 55) & (det.q[:, 0] < 265) & (det.q[:, 1] > 295) & (det.q[:, 1] < 425))


def test_no_board_and_bad_inputs_are_refused_with_clear_messages(renders):
    img, _, _, spec = renders["twin_0_0"]
    board = spec
    rng = np.random.default_rng(0)
    noise = np.clip(128 + rng.normal(0, 10, (480, 640)), 0, 255).astype(np.uint8)
    with pytest.raises(DetectionError, match="640x480 px"):
        detect_board(noise, board)
    smooth = np.tile(np.linspace(50, 200, 640), (480, 1))
    with pytest.raises(DetectionError, match="640x480"):
        detect_board(smooth, board)
    with pytest.raises(DetectionError, match="grey image"):
        detect_board(np.zeros((480, 640, 3), np.uint8), board)
    bad = img.astype(float)
    bad[0, 0] = np.nan
    with pytest.raises(DetectionError, match="non-finite"):
        detect_board(bad, board)
    with pytest.raises(DetectionError, match="min_points"):
        detect_board(img, board, min_points=500)
    with pytest.raises(DetectionError, match="Board"):
        detect_board(img, {"kind": "circles"})
    # a board with a different marker layout is not read as this one
    other = replace(spec, large_markers=((1, 1), (1, 2), (2, 1), (6, 8)))
    with pytest.raises(DetectionError):
        detect_board(img, other)


def test_board_without_markers_needs_the_full_grid_and_states_the_turn_convention(renders):
    img, R, system, spec = renders["close_no_markers"]
    board = Board(kind="circles", rows=9, cols=11, spacing_mm=20.0, small_diameter_mm=2.0)
    det = detect_board(img, board)
    assert len(det) == 99
    assert np.linalg.norm(det.q - _truth(system, board, det.ids, R), axis=1).max() < 0.1
    assert any("convention" in n for n in det.notes)
    with pytest.raises(DetectionError, match="fully in view"):
        detect_board(img[:, :400], board)


def test_docstring_examples_run():
    import doctest

    import calib.detect

    result = doctest.testmod(calib.detect)
    assert result.attempted > 0 and result.failed == 0


def test_board_half_out_of_view_identified_when_the_markers_tell_else_refused(renders):
    img, R, system, spec = renders["twin_10_20_noisy"]
    board = spec
    det = detect_board(np.ascontiguousarray(img[:, 320:]), board)      # right half: all markers, 37 circles
    truth = _truth(system, board, det.ids, R) - [320, 0]
    assert len(det) >= 30 and np.linalg.norm(det.q - truth, axis=1).max() < 0.1
    det = detect_board(np.ascontiguousarray(img[:240]), board)          # top half
    assert np.linalg.norm(det.q - _truth(system, board, det.ids, R), axis=1).max() < 0.1
    with pytest.raises(DetectionError, match="ambiguous|cannot be read"):
        detect_board(np.ascontiguousarray(img[240:]), board)            # one marker: could be mirrored
    with pytest.raises(DetectionError, match="large orientation marker"):
        detect_board(np.ascontiguousarray(img[:, :320]), board)         # no marker in view
