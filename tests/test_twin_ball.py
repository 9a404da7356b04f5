"""The twin ball of Fig. 3 rendered by synth at the pose of the real ball (experiments.twin_ball)."""
import numpy as np
import pytest

from calib.device import DeviceModel
from calib.io import load_system
from calib.system import SystemModel
from calib.triangulate import sphere_from_phase
from synth.errors import SynthError
from experiments.twin_ball import fit_ball_pose, render_twin_ball_phase
from unwrap.reliability import phase_noise_rad
from tests.conftest import shared_data
from unwrap.phase_io import read_phase


def _dp_tpu():
    d = shared_data("dp-tpu")
    real = load_system([d / "CamCalibResult_real.mat", d / "PrjCalibResult_real.mat"])
    twin_cal = load_system([d / "CamCalibResult_sim.mat", d / "PrjCalibResult_sim.mat"])
    return d, real, twin_cal, read_phase(d / "standardball_phase_real.mat")


@pytest.fixture(scope="module")
def rendered():
    d, real, twin_cal, phase_real = _dp_tpu()
    phase, info = render_twin_ball_phase(real, real.ideal(), phase_real, 96.0, progress=False)
    return real, twin_cal, phase_real, phase, info


@pytest.mark.realdata
def test_real_ball_fits_a_25_mm_sphere_about_870_mm_in_front_of_the_camera():
    _, real, _, phase_real = _dp_tpu()
    pose = fit_ball_pose(real, phase_real, 96.0)
    # no nominal size is published; 2 x 25.2 mm is within 1 % of both 50 mm and a 2-inch gauge ball
    assert 25.0 < pose["radius_mm"] < 25.5
    assert 850 < pose["centre_cam_mm"][2] < 890
    assert pose["rms_um"] < 50 and pose["points"] == int(np.isfinite(phase_real).sum())
    lin = fit_ball_pose(real, phase_real, 96.0, method="linear")
    assert np.linalg.norm(np.subtract(lin["centre_cam_mm"], pose["centre_cam_mm"])) < 1.0


@pytest.mark.realdata
def test_rendered_ball_decodes_to_its_true_phase_floor_below_a_thousandth_of_a_micron(rendered):
    real, _, phase_real, phase, info = rendered
    assert phase.dtype == np.float64 and phase.shape == phase_real.shape
    floor = info["floor"]
    assert floor["render_and_decode"]["distortion_aware_um"] < 1e-3
    assert floor["render_and_decode"]["linear_um"] < 1e-3          # the twin has no distortion
    assert info["decoding"]["float_vs_truth_rms_rad"] < 1e-6
    assert info["decoding"]["order_errors_in_footprint"] == 0
    # what the 8-bit camera adds stays a few microns
    assert floor["rendered"]["distortion_aware_um"] < 15
    assert info["pose"]["rendered_radius_mm"] == pytest.approx(floor["rendered"]["radius_mm"], abs=0.01)


@pytest.mark.realdata
def test_rendered_footprint_overlaps_the_real_one_and_has_its_pixel_count(rendered):
    _, _, phase_real, phase, info = rendered
    valid_real, valid_twin = np.isfinite(phase_real), np.isfinite(phase)
    assert valid_twin.sum() == valid_real.sum() == info["footprint"]["pixels"]
    iou = (valid_real & valid_twin).sum() / (valid_real | valid_twin).sum()
    assert iou == pytest.approx(info["footprint"]["iou"]) and iou > 0.95


@pytest.mark.realdata
def test_rendered_phase_noise_matches_the_real_phase_noise(rendered):
    _, _, phase_real, phase, info = rendered
    n = info["noise"]
    assert n["twin_rad"] == pytest.approx(n["real_rad"], rel=0.1)
    assert 1e-3 < n["real_rad"] < 5e-3
    assert n["quantisation_only_rad"] <= n["twin_rad"] * 1.02


def test_phase_noise_estimator_recovers_added_white_noise():
    v, u = np.mgrid[0:200, 0:200]
    smooth = 0.05 * u + 1e-4 * (u - 100.0) ** 2 + 1e-4 * v * u
    rng = np.random.default_rng(1)
    noisy = smooth + rng.normal(0, 0.003, smooth.shape)
    assert phase_noise_rad(noisy, smooth) == pytest.approx(0.003, rel=0.05)


@pytest.mark.realdata
def test_twin_phase_cells_fill_and_a_foreign_system_is_not_at_the_floor(rendered):
    real, twin_cal, _, phase, info = rendered
    cells = {(name, m): sphere_from_phase(s, phase, 96.0, method=m)["rms_um"]
             for name, s in (("real", real), ("twin", twin_cal)) for m in ("linear", "distortion-aware")}
    assert len(cells) == 4 and all(np.isfinite(v) and v > 0 for v in cells.values())
    floor = info["floor"]["rendered"]["distortion_aware_um"]
    # real distortion applied to a render that has none: far from the floor (the floor can fail)
    assert cells[("real", "distortion-aware")] > 3 * floor


@pytest.fixture(scope="module")
def cli_report(tmp_path_factory):
    import contextlib
    import io

    from sltwin.cli import main

    d = shared_data("dp-tpu")
    out = tmp_path_factory.mktemp("twin_ball_report")
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        rc = main(["report", "--real", str(d / "CamCalibResult_real.mat"), str(d / "PrjCalibResult_real.mat"),
                   "--twin", str(d / "CamCalibResult_sim.mat"), str(d / "PrjCalibResult_sim.mat"),
                   "--phase-real", str(d / "standardball_phase_real.mat"), "-o", str(out)])
    return rc, out, stdout.getvalue(), stderr.getvalue()


@pytest.mark.realdata
def test_report_without_a_twin_phase_renders_it_and_fills_the_matrix(cli_report):
    import json

    rc, out, stdout, stderr = cli_report
    assert rc == 0, stderr
    assert "twin ball: [5/5]" in stderr and "footprint IoU" in stdout
    summary = json.loads((out / "summary.json").read_text())
    cells = {(r["phase"], r["calibration"], r["method"]): r for r in summary["sphere_matrix"]}
    for cal in ("real", "twin"):
        for method in ("linear", "distortion-aware"):
            assert np.isfinite(cells[("real", cal, method)]["rms_um"])
            assert np.isfinite(cells[("twin (synth)", cal, method)]["rms_um"])
        assert cells[("twin (synth)", cal, "linear")]["paper_um"] is not None
    written = read_phase(out / "twin_ball_phase.h5")
    assert np.isfinite(written).sum() == summary["twin_ball"]["footprint"]["pixels"]
    assert "twin (synth)" in (out / "report.md").read_text()


@pytest.mark.realdata
def test_twin_ball_report_loads_in_a_real_browser_with_no_broken_image(cli_report):
    from tests.test_report import ARTIFACTS, _browse

    _, out, _, _ = cli_report
    shot = ARTIFACTS / "report_twin_ball.png"
    attrs, console_errors = _browse(out / "report.html", shot)
    assert int(attrs["total"]) >= 5 and attrs["ok"] == attrs["total"]
    assert console_errors == []
    assert shot.exists() and shot.stat().st_size > 10_000


@pytest.mark.realdata
def test_twin_with_another_camera_size_is_refused():
    _, real, _, phase_real = _dp_tpu()
    cam = real.camera
    small = SystemModel(DeviceModel(size=(320, 240), K=cam.K, R=cam.R, t=cam.t), real.projector)
    with pytest.raises(SynthError, match="camera image sizes differ"):
        render_twin_ball_phase(real, small, phase_real, 96.0, progress=False)


@pytest.mark.realdata
def test_bad_ball_inputs_are_refused_with_a_clear_message():
    _, real, _, phase_real = _dp_tpu()
    with pytest.raises(SynthError, match="does not match the camera image"):
        render_twin_ball_phase(real, real, phase_real[:, :320], 96.0, progress=False)
    with pytest.raises(SynthError, match="must end at the real phase's frequency 96"):
        render_twin_ball_phase(real, real, phase_real, 96.0, frequencies=(1, 8, 48), progress=False)
    with pytest.raises(SynthError, match="only 3 valid pixels"):
        few = np.full_like(phase_real, np.nan)
        few[240, 320:323] = 300.0
        fit_ball_pose(real, few, 96.0)
    with pytest.raises(SynthError, match="noise must be"):
        render_twin_ball_phase(real, real, phase_real, 96.0, noise="loud", progress=False)


@pytest.mark.realdata
def test_twin_ball_render_without_a_real_phase_is_refused(tmp_path):
    from experiments.errors import ExperimentError
    from experiments.twin_ball import twin_ball_for_report

    d = shared_data("dp-tpu")
    with pytest.raises(ExperimentError, match="needs the real ball phase"):
        twin_ball_for_report([d / "CamCalibResult_real.mat", d / "PrjCalibResult_real.mat"],
                             {"twin": d / "standardball_phase_sim.mat"}, tmp_path, render=True)
