"""Commands: ``calib render`` writes PNGs + HDF5 ground truth (DESIGN.md groups); ``calib
render-board`` writes a calibration session in the capture layout with truth.json."""
import json
import tomllib

import cv2
import h5py
import numpy as np
import pytest

from sltwin.cli import main

SCENE = """
name = "ball-on-wall"
[system]
ideal = false
[[objects]]
kind = "plane"
pose = {t = [0, 0, -100]}
[[objects]]
kind = "sphere"
radius_mm = 30
[[objects]]
kind = "blobs"
size_mm = [60, 60]
resolution = [40, 40]
pose = {t = [60, 0, -60]}
[patterns]
A = 0.5
B = 0.4
[[patterns.sequence]]
kind = "phase"
orientation = "both"
frequencies = [1, 8]
steps = 4
[[patterns.sequence]]
kind = "white"
[effects]
bits = 12
noise = {full_well_e = 20000, read_noise_e = 3, seed = 1}
"""


def test_calib_render_writes_pngs_and_hdf5_ground_truth(tmp_path, capsys):
    (tmp_path / "scene.toml").write_text(SCENE)
    assert main(["render", str(tmp_path / "scene.toml"), "-o", str(tmp_path / "out")]) == 0
    out = tmp_path / "out"
    img = cv2.imread(str(out / "v_f008_n00.png"), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint16 and img.shape == (480, 640)
    assert (out / "white.png").exists()
    with h5py.File(out / "truth.h5") as f:
        for o in ("v", "h"):
            assert f[o]["phase"].dtype == np.float64 and f[o]["order"].dtype == np.int32
            valid = f[o]["valid"][()]
            assert valid.any() and np.all(np.isnan(f[o]["phase"][()][~valid]))
            assert np.all(f[o]["order"][()][~valid] == -1)
            assert f[o].attrs["frequency"] == 8
            assert f[o]["depth" if False else "phase_f001"].shape == (480, 640)
        assert f["depth"].compression == "gzip" and f["points_cam"].shape == (480, 640, 3)
        assert f["masks/shadow"][()].any()  # the ball shadows the wall
        assert json.loads(f.attrs["system"])["camera"]["size"] == [640, 480]
        assert "cast shadows: computed" in f.attrs["render_plan"]
    assert "rendered 17 image(s)" in capsys.readouterr().out


def test_invalid_scene_is_a_clean_cli_error(tmp_path, capsys):
    (tmp_path / "bad.toml").write_text('[effects]\nbits = 9\n[patterns]\nsequence = [{kind = "white"}]')
    assert main(["render", str(tmp_path / "bad.toml"), "-o", str(tmp_path / "o")]) == 2
    assert "effects.bits" in capsys.readouterr().err


def test_calib_render_board_writes_the_capture_layout_with_truth(tmp_path):
    out = tmp_path / "captures"
    assert main(["render-board", "-o", str(out), "--poses", "2", "--steps", "3", "--frequencies", "1", "8"]) == 0
    cap = tomllib.loads((out / "capture.toml").read_text())
    assert cap["board"]["rows"] == 9 and cap["board"]["cols"] == 11 and cap["board"]["spacing_mm"] == 20.0
    assert cap["pattern"] == {"steps": [3, 3], "frequencies": [1, 8]}
    assert cap["camera"]["size"] == [640, 480] and cap["projector"]["size"] == [912, 1140]
    names = sorted(p.name for p in (out / "pose_01").iterdir())
    assert names[0] == "h_f001_n00.png" and "v_f008_n02.png" in names and "white.png" in names
    assert len(names) == 1 + 2 * 2 * 3
    truth = json.loads((out / "truth.json").read_text())
    assert len(truth["board_poses"]) == 2 and "K" in truth["camera"]
    R = np.array(truth["board_poses"][1]["R"])
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert truth["board_poses"][1]["tilt_deg"] == [10.0, 0.0, 0.0]


def test_pose_jitter_places_the_board_again_within_its_bounds_and_is_reproducible():
    from calib.rotation import rotvec_from_matrix
    from synth.scenes.board_session import pose_jitter
    from synth.errors import SynthError

    a = pose_jitter(50, 1.0, 5.0, seed=3)
    b = pose_jitter(50, 1.0, 5.0, seed=3)
    c = pose_jitter(50, 1.0, 5.0, seed=4)
    angles = np.degrees([np.linalg.norm(rotvec_from_matrix(R)) for R, _ in a])
    shifts = np.array([t for _, t in a])
    assert angles.max() <= 1.0 + 1e-12 and angles.max() > 0.8
    assert np.abs(shifts).max() <= 5.0 and np.abs(shifts).max() > 4.0
    assert all(np.array_equal(Ra, Rb) and np.array_equal(ta, tb) for (Ra, ta), (Rb, tb) in zip(a, b))
    assert not np.allclose(shifts, np.array([t for _, t in c]))
    with pytest.raises(SynthError, match="jitter"):
        pose_jitter(2, -1.0, 5.0, seed=0)


def test_jittered_session_truth_poses_are_where_the_board_was_rendered(tmp_path):
    from synth.scenes.board_session import pose_jitter, render_board_session
    from synth.scenes.poses import rotation_xyz_deg
    from calib import default_system

    out = tmp_path / "s"
    truth = render_board_session(out, steps=3, frequencies=(1,), n_poses=2, seed=5, jitter=(1.0, 5.0), noise=None)
    s = default_system()
    for i, (Rj, tj) in enumerate(pose_jitter(2, 1.0, 5.0, 5)):
        R_wb = Rj @ rotation_xyz_deg(truth["board_poses"][i]["tilt_deg"])
        assert np.allclose(truth["board_poses"][i]["R"], s.camera.R @ R_wb, atol=1e-12)
        assert np.allclose(truth["board_poses"][i]["t"], s.camera.R @ tj + s.camera.t, atol=1e-9)
    assert truth["jitter"] == [1.0, 5.0]
