"""Accepted but wrong (issue 15, item 4): the session rendered for another system, the phase file's own
frequency, and the outlier rule on the paper's real observations."""
import numpy as np
import pytest

from calib import default_system
from calib.board import Board
from calib.adjustment.problem import BAConfig
from calib.calibrate import reweight_views, run_calibration, view_noise_factors
from calib.io.outputs import outlier_summary, summary_table
from calib.simulate import simulate_observations
from calib.system import SystemModel
from sltwin.cli import main
from synth.scenes.board_session import board_reference_pose, render_board_session
from synth.scenes.boards import BoardTexture
from synth.errors import SynthError


def _in_camera_frame(s):
    """The same rig with the camera frame as world (as an OpenCV rig's file has it)."""
    R = s.projector.R @ s.camera.R.T
    t = s.projector.t - R @ s.camera.t
    return SystemModel(s.camera.with_(R=np.eye(3), t=np.zeros(3)), s.projector.with_(R=R, t=t), {})


def _visible(device, R, t, board):
    q = device.project(board.points_board() @ R.T + t)
    W, H = device.size
    return int(np.sum((q[:, 0] >= 0) & (q[:, 0] <= W - 1) & (q[:, 1] >= 0) & (q[:, 1] <= H - 1)))


def test_the_session_board_is_placed_in_the_view_of_a_system_whose_world_is_its_camera(tmp_path):
    board = BoardTexture().board
    R, t = board_reference_pose(default_system(), board)
    assert np.array_equal(R, np.eye(3)) and not t.any()   # the paper's world: the board at pose 1, unchanged
    other = _in_camera_frame(default_system().ideal())
    R, t = board_reference_pose(other, board)
    n = len(board.points_board())
    assert _visible(other.camera, R, t, board) == n and _visible(other.projector, R, t, board) == n
    truth = render_board_session(tmp_path / "s", other, steps=3, frequencies=(1, 8), n_poses=1, noise=None)
    assert truth["board_points_in_view"] == [n]
    import cv2
    white = cv2.imread(str(tmp_path / "s" / "pose_00" / "white.png"), cv2.IMREAD_UNCHANGED)
    assert np.percentile(white, 90) > 100   # exposed for the board where it stands, not for the world origin


def test_a_system_that_does_not_see_the_board_is_refused_before_rendering(tmp_path, capsys):
    s = _in_camera_frame(default_system().ideal())
    away = SystemModel(s.camera, s.projector.with_(R=np.diag([-1.0, 1.0, -1.0]) @ s.projector.R), {})
    with pytest.raises(SynthError, match="the camera sees 99 and the projector 0 of"):
        render_board_session(tmp_path / "s", away, n_poses=1)
    assert not list((tmp_path / "s").glob("pose_*"))


@pytest.fixture(scope="module")
def dp_obs():
    from conftest import shared_data
    from calib.observations import from_bouguet

    d = shared_data("dp-tpu")
    return from_bouguet(d / "CamCalibResult_real.mat", d / "PrjCalibResult_real.mat")


@pytest.mark.realdata
def test_outlier_rule_on_the_papers_observations_rejects_two_noisy_views_not_outliers(dp_obs):
    cal = run_calibration(dp_obs, BAConfig())
    rule = outlier_summary(cal, dp_obs)
    prj = rule["projector"]
    # 25 of 315 rejected where a Gaussian at the fitted noise expects 0.001: all in views 1 and 2
    assert prj["points"] == 315 and 20 <= prj["rejected"] <= 30 and prj["expected"] < 0.01
    assert set(prj["rejected_by_view"]) == {1, 2}
    table = summary_table(cal, dp_obs)
    assert "Gaussian expects" in table and "views used: 9" in table
    factors = view_noise_factors(run_calibration(dp_obs, BAConfig(outlier_threshold=None)), dp_obs)
    assert set(factors) == {"projector"} and {0, 1} <= set(factors["projector"])
    assert min(factors["projector"][v] for v in (0, 1)) > 2.5
    weighted = reweight_views(dp_obs, BAConfig())
    assert sum(r["device"] == "projector" for r in weighted.ba.rejected) <= 2


def test_views_of_equal_noise_keep_one_noise_level():
    obs, _ = simulate_observations(default_system().ideal(), Board("checkerboard", 5, 7, 20.0), 9, 0.1,
                                   np.random.default_rng(11))
    cal = reweight_views(obs, BAConfig())
    assert cal.view_noise == {}


@pytest.mark.realdata
def test_reconstruct_takes_the_frequency_from_the_phase_file(tmp_path, capsys):
    from conftest import shared_data
    from unwrap.phase_io import read_phase, write_phase_file

    d = shared_data("dp-tpu")
    phase = read_phase(d / "standardball_phase_real.mat")
    write_phase_file(tmp_path / "ball.h5", {"v": {"phase": phase}}, frequency=96.0)
    cal = [str(d / "CamCalibResult_real.mat"), str(d / "PrjCalibResult_real.mat")]
    assert main(["reconstruct", "--phase", str(tmp_path / "ball.h5"), "--calibration", *cal,
                 "-o", str(tmp_path / "a.ply")]) == 0
    from_file = capsys.readouterr().out
    assert main(["reconstruct", "--phase", str(d / "standardball_phase_real.mat"), "--frequency", "96",
                 "--calibration", *cal, "-o", str(tmp_path / "b.ply")]) == 0
    assert capsys.readouterr().out.split("->")[0] == from_file.split("->")[0]
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()
