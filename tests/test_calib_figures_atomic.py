"""The figures of `calib run` are written atomically (temporary file + rename,
unwrap.safe_output.save_figure): a drawing that fails half way leaves the previous file whole and
no temporary file behind (the residual figures are Pillow's, detections.png matplotlib's)."""
from types import SimpleNamespace

import numpy as np
import pytest
from matplotlib.figure import Figure
from PIL import Image

from calib import default_system
from calib.board import Board
from calib.io.capture_outputs import plot_detections
from calib.io.outputs import plot_residuals
from calib.pipeline import calibrate_observations
from calib.simulate import board_poses_world, simulate_observations
from calib.uncertainty.diagnostics import plot_residual_diagnostics


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    obs, _ = simulate_observations(default_system().ideal(), Board("checkerboard", 6, 8, 20.0), 6, 0.05,
                                   np.random.default_rng(5), poses=board_poses_world(6, np.random.default_rng(11)),
                                   projector_from_camera=True, noise_prj_px=0.0125)
    return calibrate_observations(obs, tmp_path_factory.mktemp("out"), figures="none", skew_check=False)


def _failing_savefig(self, fname, **kwargs):
    with open(fname, "wb") as fh:       # half a file, then the disk fills up
        fh.write(b"\x89PNG partial")
    raise OSError(28, "No space left on device")


@pytest.mark.parametrize("which", ["summary", "per_pose", "detections"])
def test_a_failed_figure_write_leaves_the_previous_file(run, tmp_path, monkeypatch, which):
    cal, obs = run.calibration, run.observations
    names = {"summary": ["residuals.png"], "per_pose": ["residuals_per_pose.png", "residuals_on_board.png"],
             "detections": ["detections.png"]}[which]
    for n in names:
        (tmp_path / n).write_bytes(b"previous")
    monkeypatch.setattr(Figure, "savefig", _failing_savefig)
    monkeypatch.setattr(Image.Image, "save", _failing_savefig)      # the summary figure: Pillow's PNG
    with pytest.raises(OSError):
        if which == "summary":
            plot_residuals(cal, obs, tmp_path / "residuals.png")
        elif which == "detections":
            pose = SimpleNamespace(image=None, q_cam=np.array([[10.0, 20.0], [30.0, 40.0]]),
                                   q_prj=np.array([[1.0, 2.0], [np.nan, np.nan]]), name="pose1", ids=[0, 1],
                                   board_image="board.png")
            plot_detections(SimpleNamespace(poses=[pose]), tmp_path / "detections.png")
        else:
            plot_residual_diagnostics(cal, obs, cal.uncertainty.diagnostics, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(names)     # no temporary file left
    assert all((tmp_path / n).read_bytes() == b"previous" for n in names)
