"""calib run CAPTURES, stages 2-3: projector pixels of board features from the decoded phase, and
the capture-folder failure modes (missing / truncated frames, wrong step counts, low modulation).

The board detector is replaced here by the true projection of the board points (the renderer's
truth), so these tests measure the phase fit and the capture handling alone; detection has its own
tests.
"""
import json
import shutil
import tomllib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import tomli_w

from calib.detect.captures import CaptureError, observations_from_captures, read_session
from calib.io.calibration_json import system_from_dict
from calib.detect.marker_phase import MarkerPhaseError, fit_projector_points, window_radii
from calib.observations import ObservationError


def truth_detector(folder, camera_noise_px=0.0):
    """A detector that returns the true camera pixels of the board points fully inside the image,
    pose by pose in the order of the capture's pose folders."""
    truth = json.loads((Path(folder) / "truth.json").read_text())
    system = system_from_dict(truth)
    cam = system.camera
    rng = np.random.default_rng(7)
    calls = {"pose": 0}

    def detect(image, board):
        i = calls["pose"]
        calls["pose"] += 1
        pose = truth["board_poses"][i]
        P = board.points_board()
        X_cam = P @ np.asarray(pose["R"]).T + np.asarray(pose["t"])
        q = cam.project((X_cam - cam.t) @ cam.R)
        H, W = image.shape
        keep = (q[:, 0] > 8) & (q[:, 0] < W - 9) & (q[:, 1] > 8) & (q[:, 1] < H - 9)
        ids = np.nonzero(keep)[0]
        radius_px = np.where(board.is_large(), board.large_diameter_mm, board.small_diameter_mm) / 2 \
            * cam.K[0, 0] / X_cam[:, 2]
        return SimpleNamespace(ids=ids, q=q[keep] + rng.normal(0, camera_noise_px, (len(ids), 2)),
                               points_board=P[keep], feature_px=radius_px[keep], notes=[])

    return detect, system, truth


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """Three poses of the paper's session rendered in the ideal-pinhole twin, with sensor noise."""
    from calib import default_system
    from synth.scenes.board_session import render_board_session

    s = default_system()
    twin = s.ideal({})
    out = tmp_path_factory.mktemp("captures")
    render_board_session(out, twin, n_poses=3, steps=12, frequencies=(1, 8, 48))
    return out


def copy_session(src, dst):
    shutil.copytree(src, dst)
    return dst


def true_projector_pixels(system, truth, i, board, ids):
    pose = truth["board_poses"][i]
    X_cam = board.points_board(ids) @ np.asarray(pose["R"]).T + np.asarray(pose["t"])
    cam = system.camera
    return system.projector.project((X_cam - cam.t) @ cam.R)


def test_local_phase_fit_gives_projector_pixels_within_their_predicted_standard_error(session):
    detect, system, truth = truth_detector(session)
    co = observations_from_captures(session, detector=detect)
    errors, sigmas = [], []
    for i, p in enumerate(co.poses):
        q_true = true_projector_pixels(system, truth, i, co.session.board, p.ids)
        assert np.isfinite(p.q_prj).all(), p.notes
        errors.append(p.q_prj - q_true)
        sigmas.append(p.sigma_prj)
    e = np.concatenate(errors)
    s = np.concatenate(sigmas)
    rms_error = np.sqrt(np.mean(np.sum(e ** 2, axis=1) / 2))
    rms_sigma = np.sqrt(np.mean(s ** 2))
    # the predicted standard error describes the actual error (within a factor 1.6 either way)
    assert rms_sigma / 1.6 < rms_error < 1.6 * rms_sigma, (rms_error, rms_sigma)
    assert np.max(np.abs(e)) < 0.05


def test_quadratic_window_model_removes_the_curvature_bias_of_an_affine_one(session):
    from unwrap.patterns import projector_coordinate
    from unwrap.pipeline import unwrap_capture

    detect, system, truth = truth_detector(session)
    board = read_session(session).board
    det = detect(np.zeros((480, 640)), board)
    res = unwrap_capture(session, pose="pose_00")
    u = projector_coordinate(res["v"].result.phase, res["v"].result.frequency, res["v"].width)
    v = projector_coordinate(res["h"].result.phase, res["h"].result.frequency, res["h"].width)
    radius, inner = window_radii(det.q, det.feature_px)
    q_true = true_projector_pixels(system, truth, 0, board, det.ids)
    rms = {}
    for degree in (1, 2):
        fit = fit_projector_points(det.q, u, v, weight_u=res["v"].modulation ** 2, weight_v=res["h"].modulation ** 2,
                                   radius_px=radius, inner_px=inner, degree=degree)
        rms[degree] = float(np.sqrt(np.mean((fit.q_prj - q_true) ** 2)))
    assert rms[2] < rms[1] / 3, rms


def test_phase_fit_refuses_inconsistent_inputs_by_name():
    u = np.zeros((20, 30))
    with pytest.raises(MarkerPhaseError, match="shape"):
        fit_projector_points(np.zeros((3, 3)), u, u)
    with pytest.raises(MarkerPhaseError, match="differ in shape"):
        fit_projector_points(np.zeros((1, 2)), u, np.zeros((21, 30)))
    with pytest.raises(MarkerPhaseError, match="radii"):
        fit_projector_points(np.zeros((1, 2)), u, u, radius_px=3.0, inner_px=5.0)


def test_feature_outside_the_image_or_on_nan_phase_fails_with_a_reason_not_a_number():
    yy, xx = np.mgrid[0:40, 0:40].astype(float)
    u = 3.0 * xx
    u[:, 20:] = np.nan
    fit = fit_projector_points(np.array([[10.0, 10.0], [30.0, 10.0], [500.0, 500.0], [np.nan, 3.0]]), u, u,
                               radius_px=6.0)
    assert fit.ok.tolist() == [True, False, False, False]
    assert np.isnan(fit.q_prj[1:]).all() and set(fit.reasons) == {1, 2, 3}
    assert "outside" in fit.reasons[2] and "not finite" in fit.reasons[3]


def test_low_modulation_markers_lose_their_projector_pixels_but_keep_their_camera_pixels(session, tmp_path):
    import cv2

    folder = copy_session(session, tmp_path / "c")
    detect, system, truth = truth_detector(folder)
    board = read_session(folder).board
    q = detect(np.zeros((480, 640)), board).q
    x, y = (int(round(c)) for c in q[len(q) // 2])
    for f in (folder / "pose_00").glob("[vh]_f*_n*.png"):       # a 70x70 px patch with no fringes
        img = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        img[y - 35:y + 35, x - 35:x + 35] = 90
        cv2.imwrite(str(f), img)
    detect, *_ = truth_detector(folder)
    co = observations_from_captures(folder, detector=detect)
    p = co.poses[0]
    lost = ~np.isfinite(p.q_prj).all(axis=1)
    assert 1 <= lost.sum() <= 4
    assert np.isfinite(p.q_cam[lost]).all()
    assert any("not fitted" in n for n in p.notes)


def test_missing_and_truncated_frames_skip_the_pose_with_the_file_named_or_refuse_when_strict(session, tmp_path):
    folder = copy_session(session, tmp_path / "c")
    (folder / "pose_01" / "v_f048_n05.png").unlink()
    png = folder / "pose_02" / "h_f008_n03.png"
    png.write_bytes(png.read_bytes()[: png.stat().st_size // 3])
    detect, *_ = truth_detector(folder)
    with pytest.raises(ObservationError, match="1 usable pose"):
        observations_from_captures(folder, detector=detect)
    detect, *_ = truth_detector(folder)
    co = observations_from_captures(folder, detector=detect, min_poses=1)
    assert [p.name for p in co.poses] == ["pose_00"]
    assert "v_f048_n05" in co.skipped["pose_01"]
    assert "h_f008_n03" in co.skipped["pose_02"]
    detect, *_ = truth_detector(folder)
    with pytest.raises(CaptureError, match="pose_01.*v_f048_n05"):
        observations_from_captures(folder, detector=detect, strict=True, min_poses=1)


def test_wrong_step_count_is_refused_not_decoded_with_wrong_shifts(session, tmp_path):
    folder = copy_session(session, tmp_path / "c")
    toml = folder / "capture.toml"
    meta = tomllib.loads(toml.read_text())
    assert meta["pattern"]["steps"] == [12, 12, 12]
    meta["pattern"]["steps"] = [11, 11, 11]
    toml.write_text(tomli_w.dumps(meta))
    detect, *_ = truth_detector(folder)
    with pytest.raises(CaptureError, match="wrong step count"):
        observations_from_captures(folder, detector=detect, strict=True)


def test_capture_description_errors_name_the_key(tmp_path):
    with pytest.raises(CaptureError, match="capture folder not found"):
        read_session(tmp_path / "nope")
    (tmp_path / "pose_00").mkdir()
    with pytest.raises(CaptureError, match="capture.toml"):
        read_session(tmp_path)
    (tmp_path / "capture.toml").write_text("[pattern]\nsteps = 4\nfrequencies = [1, 8]\n")
    with pytest.raises(CaptureError, match=r"\[board\]"):
        read_session(tmp_path)
    (tmp_path / "capture.toml").write_text('[board]\nkind = "checkerboard"\nrows = 4\ncols = 5\nspacing_mm = 10\n'
                                           "[pattern]\nsteps = 4\n")
    with pytest.raises(CaptureError, match="frequencies"):
        read_session(tmp_path)


def test_camera_detection_error_carries_into_the_projector_pixel_as_the_fit_gradient_predicts(session):
    """A phase-shifting projector pixel is read at the detected camera pixel: a detection error e
    moves it by dprj_dcam @ e. With 0.05 px of camera error (more than the phase fit's ~0.001 px),
    the projector pixel errors are explained by the fitted gradient down to the phase fit's own
    standard error, and that gradient equals the exact derivative of the read-out."""
    from calib.simulate import projector_pixels_at_camera_pixels, projector_readout_jacobian

    detect, system, truth = truth_detector(session, camera_noise_px=0.05)
    exact, _, _ = truth_detector(session)
    co = observations_from_captures(session, detector=detect)
    Rc, tc = system.camera.R, system.camera.t
    raw, explained, sig, grad_err = [], [], [], []
    for i, p in enumerate(co.poses):
        q_cam_true = exact(np.zeros((480, 640)), co.session.board).q
        pose = truth["board_poses"][i]
        R_wb = Rc.T @ np.asarray(pose["R"])
        t_wb = Rc.T @ (np.asarray(pose["t"]) - tc)
        e_cam = p.q_cam - q_cam_true
        q_prj_true = projector_pixels_at_camera_pixels(system, R_wb, t_wb, q_cam_true)
        A = p.dprj_dcam
        assert A.shape == (len(p.ids), 2, 2) and np.isfinite(A).all()
        A_exact = projector_readout_jacobian(system, R_wb, t_wb, q_cam_true)
        grad_err.append(np.abs(A - A_exact).max() / np.abs(A_exact).max())
        raw.append(p.q_prj - q_prj_true)
        explained.append(p.q_prj - q_prj_true - np.einsum("kij,kj->ki", A, e_cam))
        sig.append(p.sigma_prj)
    raw, explained, sig = np.concatenate(raw), np.concatenate(explained), np.concatenate(sig)
    rms = lambda a: float(np.sqrt(np.mean(a ** 2)))
    print(f"gradient rel. error {max(grad_err):.2e}; projector error RMS raw {rms(raw):.5f} px, after A e {rms(explained):.5f} px, predicted {rms(sig):.5f} px")
    assert max(grad_err) < 2e-3, grad_err
    assert rms(raw) > 20 * rms(sig), (rms(raw), rms(sig))          # the camera error dominates the raw read-out
    assert rms(explained) < 1.6 * rms(sig), (rms(explained), rms(sig))  # and the gradient explains it


def test_a_skipped_pose_is_a_warning_so_quiet_runs_still_show_it(session, tmp_path, caplog):
    import logging

    folder = copy_session(session, tmp_path / "c")
    (folder / "pose_01" / "v_f048_n05.png").unlink()
    detect, *_ = truth_detector(folder)
    with caplog.at_level(logging.WARNING, logger="calib"):   # what calib run -q shows
        co = observations_from_captures(folder, detector=detect, min_poses=1)
    assert [r.getMessage() for r in caplog.records if "pose_01: skipped" in r.getMessage()]
    assert list(co.skipped) == ["pose_01"]


def test_a_camera_model_switches_the_detector_to_the_lens_aware_centre_correction(session):
    """observations_from_captures(camera=...) detects with the lens-aware correction; with the twin's
    distortion-free lens it equals the perspective correction, so the centres stay on the truth."""
    truth = json.loads((Path(session) / "truth.json").read_text())
    system = system_from_dict(truth)
    co = observations_from_captures(session, camera=system.camera)
    assert all(any("perspective + lens bias corrected" in n for n in p.notes) for p in co.poses)
    for i, p in enumerate(co.poses):
        pose = truth["board_poses"][i]
        X_cam = p.points_board @ np.asarray(pose["R"]).T + np.asarray(pose["t"])
        q_true = system.camera.project((X_cam - system.camera.t) @ system.camera.R)
        assert np.sqrt(np.mean(np.sum((p.q_cam - q_true) ** 2, axis=1))) < 0.04     # as without it (~0.017 px)
