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


@pytest.mark.parametrize("n_distortion", [0, 4, 5, 8, 12])
def test_cameramodel_written_without_mrcal_is_byte_for_byte_mrcals(tmp_path, n_distortion):
    """write_cameramodel writes mrcal's text itself (no mrcal import in calib run): the same bytes
    as mrcal.cameramodel.write, for every lens model, a dropped skew's note included."""
    import mrcal

    dev = getattr(default_system(), "projector")          # skew -0.95 px: dropped at a 0.2 px tolerance
    dist = np.resize(np.asarray(dev.distortion, float) * 0.5 + 1e-3, n_distortion)
    dev = dev.with_(distortion=dist)
    report = write_cameramodel(dev, tmp_path / "ours.cameramodel", skew_tol_px=0.2)
    model, report_mrcal = to_cameramodel(dev, skew_tol_px=0.2)
    model.write(str(tmp_path / "mrcal.cameramodel"), note=f"sltwin {dev.kind}; {'; '.join(report)}")
    assert report == report_mrcal and "dropped" in report[0]
    assert (tmp_path / "ours.cameramodel").read_bytes() == (tmp_path / "mrcal.cameramodel").read_bytes()


def test_mrcal_refuses_skew_it_cannot_hold_and_names_the_pixel_effect():
    prj = default_system().projector  # skew -0.95 px: 0.16 px at the corners
    with pytest.raises(FormatError, match=r"skew s = -0.951.*0\.16\d\d px"):
        to_cameramodel(prj)
    model, report = to_cameramodel(prj, skew_tol_px=0.2)
    assert "dropped" in report[0] and skew_effect_px(prj) == pytest.approx(0.1617, abs=1e-4)


@pytest.mark.realdata
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


@pytest.mark.realdata
def test_slstudio_opencv_xml(tmp_path):
    path = shared_data("slstudio-ps2x3-calib", "calibration", "calibration.xml")
    s = load_system(path)
    assert s.camera.size == (1688, 1352) and s.projector.size == (1824, 1140)
    assert s.camera.fx == pytest.approx(2195.12036, rel=1e-7)
    assert s.projector.t[0] == pytest.approx(-145.282562, rel=1e-7)
    np.testing.assert_allclose(s.projector.distortion, [-0.0314900056, 0, 0, 0, 0], rtol=1e-7)


@pytest.mark.realdata
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


def _write_storage(path, entries):
    import cv2

    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in entries.items():
        fs.write(key, np.asarray(value, dtype=np.float64) if not np.isscalar(value) else float(value))
    fs.release()
    return path


PROCAM = {  # kamino410/procam-calibration's calibration_result.xml layout, values of its sample file
    "img_shape": [[1024.0], [1280.0]], "rms": 0.425,
    "cam_int": [[3452.39, 0, 587.17], [0, 3449.92, 521.45], [0, 0, 1]],
    "cam_dist": [[-0.2223, -0.8664, -0.00073, -0.00169, 3.1325]],
    "proj_int": [[1947.16, 0, 448.86], [0, 1933.99, 719.97], [0, 0, 1]],
    "proj_dist": [[-0.0912, 1.1448, -0.00227, -0.00931, -7.798]],
    "roration": [[0.99907286, 0.01455773, -0.04051535], [-0.01206627, 0.99806035, 0.06107332],
                 [0.04132585, -0.06052783, 0.99731066]],
    "translation": [[39.063], [-278.264], [-61.947]]}


def test_procam_calibration_xml_with_its_rotation_typo_and_rows_cols_image_shape(tmp_path):
    path = _write_storage(tmp_path / "calibration_result.xml", PROCAM)
    with pytest.raises(FormatError, match="projector image size is not stored.*projector_size"):
        load_system(path)
    s = load_system(path, projector_size=(1024, 768))
    assert s.camera.size == (1280, 1024) and s.projector.size == (1024, 768)    # img_shape is (rows, cols)
    assert s.camera.fx == pytest.approx(3452.39) and s.projector.cy == pytest.approx(719.97)
    np.testing.assert_allclose(s.projector.t, [39.063, -278.264, -61.947])
    keys = s.meta["source"]["keys"]
    assert keys["R_prj_cam"] == "roration" and keys["camera_size"] == "img_shape (rows, cols)"
    assert s.meta["source"]["format"] == "opencv-filestorage (procam)"
    fixed = dict(PROCAM, rotation=PROCAM["roration"])
    del fixed["roration"]
    s2 = load_system(_write_storage(tmp_path / "fixed.xml", fixed), projector_size=(1024, 768))
    assert s2.meta["source"]["keys"]["R_prj_cam"] == "rotation"


@pytest.mark.parametrize("order", ["rows_cols", "width_height"])
def test_image_size_written_either_way_is_read_by_where_the_principal_point_lies(tmp_path, order):
    entries = {k: v for k, v in PROCAM.items() if k not in ("img_shape", "roration")}
    entries["rotation"] = PROCAM["roration"]
    entries["imageSize"] = [1024, 1280] if order == "rows_cols" else [1280, 1024]
    s = load_system(_write_storage(tmp_path / "c.yml", entries), projector_size=(1024, 768))
    assert s.camera.size == (1280, 1024)
    assert s.meta["source"]["keys"]["camera_size"].startswith(
        "imageSize read as " + ("(rows, cols)" if order == "rows_cols" else "(width, height)"))


def test_incomplete_key_sets_are_refused_naming_what_was_found_and_expected(tmp_path):
    entries = {k: v for k, v in PROCAM.items() if k != "translation"}
    with pytest.raises(FormatError, match=r"found keys \[.*cam_int.*\].*procam: cam_int.*rotation \| roration"):
        load_system(_write_storage(tmp_path / "c.xml", entries), projector_size=(1024, 768))
