"""Readers and writers: calibration.json, mrcal .cameramodel, Bouguet .mat, OpenCV FileStorage."""
import json

import numpy as np
import pytest

from calib import DeviceModel, FormatError, ModelError, default_system, load_system
from calib.io.calibration_json import read_calibration_json, write_calibration_json
from calib.io.mrcal_model import read_cameramodel, skew_effect_px, to_cameramodel, write_cameramodel
from tests.conftest import shared_data


def test_calibration_json_round_trip_is_exact(tmp_path):
    s = default_system()
    path = write_calibration_json(s, tmp_path / "calibration.json")
    d = json.loads(path.read_text())
    assert d["units"] == "mm" and set(d["camera"]) >= {"size", "K", "distortion", "R", "t"}
    back = read_calibration_json(path)
    for a, b in ((s.camera, back.camera), (s.projector, back.projector)):
        np.testing.assert_array_equal(a.K, b.K)
        np.testing.assert_array_equal(a.R, b.R)
        np.testing.assert_array_equal(a.t, b.t)
    assert back.meta["datasheets"]["projector"]["dmd_size_mm"] == [10.8, 6.8]


@pytest.mark.parametrize("content, message", [
    ("{", "not valid JSON"),
    ('{"camera": {}}', "missing key"),
    ('{"units": "inch", "camera": {}, "projector": {}}', "units"),
    ('{"camera": {"size": [640, 480]}, "projector": {}}', r"missing keys \['K'\]"),
])
def test_broken_calibration_json_is_refused_by_name(tmp_path, content, message):
    p = tmp_path / "c.json"
    p.write_text(content)
    with pytest.raises((FormatError, ModelError), match=message):
        load_system(p)


def _no_skew(dev):
    K = np.array(dev.K)
    K[0, 1] = 0
    return dev.with_(K=K)


@pytest.mark.parametrize("kind", ["camera", "projector"])
def test_mrcal_cameramodel_round_trip(tmp_path, kind):
    import mrcal

    dev = _no_skew(getattr(default_system(), kind))
    write_cameramodel(dev, tmp_path / f"{kind}.cameramodel")
    model = mrcal.cameramodel(str(tmp_path / f"{kind}.cameramodel"))  # mrcal's own reader
    assert model.intrinsics()[0] == "LENSMODEL_OPENCV5"
    back = read_cameramodel(tmp_path / f"{kind}.cameramodel", kind=kind)
    # mrcal writes 10 significant digits
    np.testing.assert_allclose(back.K, dev.K, rtol=1e-9)
    np.testing.assert_allclose(back.R, dev.R, atol=1e-9)
    np.testing.assert_allclose(back.t, dev.t, rtol=1e-9, atol=1e-9)
    # mrcal projects world points exactly as we do
    X = np.array([[10.0, -20.0, 0.0], [-60.0, 40.0, 5.0]])
    q_mrcal = mrcal.project(mrcal.transform_point_rt(model.extrinsics_rt_fromref(), X), *model.intrinsics())
    np.testing.assert_allclose(q_mrcal, dev.project(X), atol=1e-8)


def test_mrcal_refuses_skew_it_cannot_hold_and_names_the_pixel_effect():
    prj = default_system().projector  # skew -0.95 px: 0.16 px at the corners
    with pytest.raises(FormatError, match=r"skew s = -0.951.*0\.16\d\d px"):
        to_cameramodel(prj)
    model, report = to_cameramodel(prj, skew_tol_px=0.2)
    assert "dropped" in report[0] and skew_effect_px(prj) == pytest.approx(0.1617, abs=1e-4)


def test_bouguet_pair_reads_the_papers_system_with_pose_1_as_world(dp_tpu_dir):
    from calib.io.bouguet import read_bouguet

    s = load_system([dp_tpu_dir / "CamCalibResult_real.mat", dp_tpu_dir / "PrjCalibResult_real.mat"])
    ref = default_system()
    np.testing.assert_array_equal(s.camera.K, ref.camera.K)
    np.testing.assert_array_equal(s.projector.t, ref.projector.t)
    r = read_bouguet(dp_tpu_dir / "CamCalibResult_real.mat")
    assert len(r.points_px) == 9 and r.points_px[0].shape == (35, 2) and r.points_board[0].shape == (35, 3)
    # the stored observations reproject through the stored model (Bouguet: x = KK distort(R X + T))
    for i in range(9):
        q = r.device("camera", i).project(r.points_board[i])
        assert np.sqrt(np.mean((q - r.points_px[i]) ** 2)) < 0.2


def test_slstudio_opencv_xml(tmp_path):
    path = shared_data("slstudio-ps2x3-calib", "calibration", "calibration.xml")
    s = load_system(path)
    assert s.camera.size == (1688, 1352) and s.projector.size == (1824, 1140)
    assert s.camera.fx == pytest.approx(2195.12036, rel=1e-7)
    assert s.projector.t[0] == pytest.approx(-145.282562, rel=1e-7)
    np.testing.assert_allclose(s.projector.distortion, [-0.0314900056, 0, 0, 0, 0], rtol=1e-7)


def test_slmaster_opencv_yaml_needs_the_projector_size_it_does_not_store():
    path = shared_data("slmaster-monocular-12step-cgc", "caliInfo.yml")
    with pytest.raises(FormatError, match="projector image size is not stored"):
        load_system(path)
    s = load_system(path, projector_size=(1920, 1080))
    assert s.camera.size == (1280, 1024) and s.projector.fx == pytest.approx(2496.6331464214777)


def test_unknown_formats_are_refused(tmp_path):
    (tmp_path / "a.txt").write_text("x")
    with pytest.raises(FormatError, match="cannot tell the format"):
        load_system(tmp_path / "a.txt")
    with pytest.raises(FormatError, match="no such file"):
        load_system(tmp_path / "missing.json")


def test_cli_twin_prints_table_s3_and_refuses_bad_input_without_traceback(tmp_path, capsys):
    from sltwin.cli import main

    assert main(["twin", "-o", str(tmp_path / "twin.json"), "--blender-script", str(tmp_path / "s.py")]) == 0
    out = capsys.readouterr().out
    assert "INCONSISTENT" in out and "14 of 17 printed values reproduce" in out
    twin = json.loads((tmp_path / "twin.json").read_text())
    assert set(twin["camera"]) >= {"rotation_euler_deg", "location_mm", "focal_length_mm", "sensor_size_mm",
                                   "shift", "resolution", "pixel_aspect", "not_representable"}
    assert "def build_twin_scene" in (tmp_path / "s.py").read_text()
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"camera": {"size": [640, 480], "K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
                                          "R": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]},
                               "projector": {"size": [912, 1140], "K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}}))
    assert main(["twin", str(bad), "-o", str(tmp_path / "t2.json")]) == 2
    assert "reflection" in capsys.readouterr().err
