"""Checkerboard and ChArUco detection: rendered checkerboards against the true projections and our
id convention (row 0 at the bottom of the printed face), ChArUco boards with perspective and
partial views, and the real SLStudio and OpenCV sample images."""
import cv2
import numpy as np
import pytest

from calib.board import Board
from calib.detect import DetectionError, detect_board
from bench.detect_accuracy import render_white
from calib.detect.result import apply_homography
from calib.system import default_system
from tests.conftest import shared_data


@pytest.fixture(scope="session")
def checker_renders(tmp_path_factory):
    cache = tmp_path_factory.mktemp("detect_checker")
    system = default_system()
    out = {}
    for name, (rows, cols, tilt) in {"odd_10_20": (5, 8, (10, 20)), "odd_turned": (5, 8, (-10, 0, 180)),
                                     "even_0_0": (6, 8, (0, -20))}.items():
        board = Board(kind="checkerboard", rows=rows, cols=cols, spacing_mm=15.0)
        path = cache / f"{name}.npz"
        if path.exists():
            d = np.load(path)
            img, R = d["img"], d["R"]
        else:
            img, R = render_white(system, board, tilt, noise_seed=1)
            np.savez(path, img=img, R=R)
        out[name] = (img, R, system, board)
    return out


@pytest.mark.parametrize("name", ["odd_10_20", "odd_turned"])
def test_checkerboard_corners_match_the_true_projections_and_our_ids(checker_renders, name):
    img, R, system, board = checker_renders[name]
    det = detect_board(img, board)
    assert len(det) == board.n_points and np.array_equal(det.ids, np.arange(board.n_points))
    truth = system.camera.project(board.points_board(det.ids) @ R.T)
    err = np.linalg.norm(det.q - truth, axis=1)
    assert err.max() < 0.2, err.max()        # SB + cornerSubPix: ~0.08 px RMS on these renders
    assert any("square colours" in n for n in det.notes)   # rows + cols odd: colours fix the turn
    assert np.allclose(det.feature_px, 0.5 * 15.0 * 2592 / 850, rtol=0.25)


def test_checkerboard_with_even_rows_plus_cols_states_its_convention(checker_renders):
    img, R, system, board = checker_renders["even_0_0"]
    det = detect_board(img, board)
    assert any("convention" in n for n in det.notes)
    # board +y up in the image; here that is the true orientation
    truth = system.camera.project(board.points_board(det.ids) @ R.T)
    assert np.linalg.norm(det.q - truth, axis=1).max() < 0.2


def test_checkerboard_not_in_view_is_refused(checker_renders):
    img, _, _, board = checker_renders["odd_10_20"]
    with pytest.raises(DetectionError, match="board not found.*fully in view"):
        detect_board(img[:, :300], board)
    wrong = Board(kind="checkerboard", rows=7, cols=9, spacing_mm=15.0)
    with pytest.raises(DetectionError, match="640x480"):
        detect_board(img, wrong)


def _charuco_image(board_px=60, margin=40):
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_1000)
    cb = cv2.aruco.CharucoBoard((8, 6), 20.0, 15.0, d)
    img = cb.generateImage((8 * board_px, 6 * board_px), marginSize=0)
    img = cv2.copyMakeBorder(img, margin, margin, margin, margin, cv2.BORDER_CONSTANT, value=255)
    Hw = np.array([[0.9, 0.12, 60], [-0.05, 0.85, 50], [2e-4, 1e-4, 1.0]])
    return cv2.warpPerspective(img, Hw, (720, 560), flags=cv2.INTER_AREA, borderValue=255), Hw


def test_charuco_corners_carry_our_ids_and_survive_a_partial_view():
    board = Board(kind="charuco", rows=5, cols=7, spacing_mm=20.0, extra={"marker_mm": 15.0})
    img, Hw = _charuco_image()
    det = detect_board(img, board)
    assert len(det) == 35
    r, c = det.ids // 7, det.ids % 7
    # generated image: OpenCV's corner row r_cv counts from the top, pixel edges at k*60 - 0.5
    true = apply_homography(Hw, np.c_[(c + 1) * 60 - 0.5 + 40, (4 - r + 1) * 60 - 0.5 + 40])
    err = np.linalg.norm(det.q - true, axis=1)
    assert err.max() < 0.8 and np.sqrt(np.mean(err ** 2)) < 0.4   # the warp's resampling limits the truth
    # proper orientation: board +x right, +y up in this view
    o, x, y = apply_homography(det.homography, [[0, 0], [20, 0], [0, 20]])
    assert x[0] > o[0] and y[1] < o[1]
    part = det.ids
    det2 = detect_board(img[:, :380], board)
    assert 8 <= len(det2) < 35 and set(det2.ids) <= set(part)
    np.testing.assert_allclose(det2.q, det.q[np.searchsorted(det.ids, det2.ids)], atol=0.3)


def test_charuco_without_marker_size_is_refused():
    board = Board(kind="charuco", rows=5, cols=7, spacing_mm=20.0)
    img, _ = _charuco_image()
    with pytest.raises(DetectionError, match="marker_mm"):
        detect_board(img, board)


@pytest.mark.realdata
def test_slstudio_real_board_all_6_poses_full_117_corners():
    root = shared_data("slstudio-ps2x3-calib", "calibration")
    board = Board(kind="checkerboard", rows=13, cols=9, spacing_mm=10.0)
    for pose in range(1, 7):
        frames = [cv2.imread(str(root / f"calseq{pose}" / f"frameSeq_{i:02d}.png"), cv2.IMREAD_GRAYSCALE)
                  for i in range(3)]
        mean = np.mean(np.stack(frames).astype(np.float64), axis=0)   # the 3-step mean A
        det = detect_board(mean, board)
        assert len(det) == 117, pose
        assert np.array_equal(det.ids, np.arange(117))
        # a real lens (k1 ~ -0.06): the plane homography explains the corners to about a pixel
        assert det.reprojection_rms_px() < 1.5, (pose, det.reprojection_rms_px())
        assert 15 < np.median(det.feature_px) < 60


@pytest.mark.realdata
def test_opencv_sample_chessboards_all_13_left_images():
    root = shared_data("opencv-stereo-chessboard")
    board = Board(kind="checkerboard", rows=6, cols=9, spacing_mm=1.0)
    found = 0
    for path in sorted(root.glob("left*.jpg")):
        det = detect_board(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), board)
        found += len(det) == 54
    assert found == 13
