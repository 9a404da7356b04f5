"""Twin mapping: paper table S3 and eqs. S1-S3, round trips, and the hard cases."""
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from calib import DeviceModel, ModelError, default_system
from calib.rotation import matrix_from_rotvec
from twin_mapping import (DLP4500, BASLER_ACA640_750UM, Datasheet, TwinError, check_table_s2_rotations,
                          compare_with_table_s3, device_to_twin, from_twin, to_twin, twin_to_device)
from twin_mapping.euler import euler_xyz_from_matrix, matrix_from_euler_xyz, paper_s1_angles

GENERIC = Datasheet("test sensor", (640, 480), (5.0, 5.0))


def _rows_by_key():
    rows = compare_with_table_s3(to_twin(default_system()))
    return {(r["device"], r["quantity"], r["axis"]): r for r in rows}


def test_table_s3_reproduces_from_full_precision_data_except_the_misprinted_camera_x():
    rows = _rows_by_key()
    s3 = [k for k in rows if k[1] in ("rotation_euler_deg", "location_mm")]
    assert len(s3) == 12
    bad = [k for k in s3 if rows[k]["status"] != "reproduces"]
    assert bad == [("camera", "location_mm", "x")]
    # every other value is ours truncated (or rounded) to the 4 printed decimals
    for k in s3:
        if k not in bad:
            assert abs(rows[k]["difference"]) < 1e-4, k


def test_table_s3_camera_x_location_misses_a_digit():
    r = _rows_by_key()[("camera", "location_mm", "x")]
    assert r["status"] == "INCONSISTENT"
    assert r["ours"] == pytest.approx(109.1985, abs=1e-4) and r["printed"] == 10.1985
    assert "digit '9' dropped" in r["note"]


def test_table_s3_is_truncated_not_rounded():
    rows = _rows_by_key()
    # 4.48229... prints as 4.4822 and -86.25016 as -86.2501: truncation toward zero
    assert rows[("camera", "rotation_euler_deg", "x")]["note"].endswith("truncated to 4 decimals")
    assert rows[("projector", "location_mm", "y")]["note"].endswith("truncated to 4 decimals")


def test_focal_lengths_in_mm_of_eqs_s1_s3():
    rows = _rows_by_key()
    assert rows[("camera", "focal_length_mm", "x")]["status"] == "reproduces"   # 12.4423
    assert rows[("camera", "focal_length_mm", "y")]["status"] == "reproduces"   # 12.4449
    prj = rows[("projector", "focal_length_mm", "x")]
    # exact DMD pitch 10.8 mm / 912 gives 20.5125 mm; the paper used its rounded 11.84 um -> 20.5089
    assert prj["ours"] == pytest.approx(20.5125, abs=1e-4)
    assert prj["status"] == "DOES NOT REPRODUCE" and "reproduces (20.50885 mm)" in prj["note"]


def test_eq_s2_projector_pitch_divides_by_1024_rows_not_1140():
    r = _rows_by_key()[("projector", "pixel_pitch_um", "y")]
    assert r["status"] == "DOES NOT REPRODUCE"
    assert "6.8 mm / 1024 px" in r["note"] and r["ours"] == pytest.approx(6.8 / 1140 * 1000)


def test_printed_s2_camera_rotation_is_not_a_rotation_because_r31_lost_its_sign():
    s = default_system()
    cam, prj = check_table_s2_rotations({"camera": s.camera.R, "projector": s.projector.R})
    assert cam["det"] == pytest.approx(0.9615, abs=1e-4)
    assert cam["entries_off"] == [{"row": 3, "col": 1, "printed": 0.135, "full_precision": pytest.approx(-0.13504, abs=1e-5)}]
    assert cam["det_after_sign_fix"] == pytest.approx(1.0, abs=0.003)
    assert prj["entries_off"] == [] and prj["max_orthonormality_error"] < 0.002


def test_printed_s2_camera_rotation_is_refused_unless_repair_is_asked_for_and_then_reported():
    from twin_mapping.paper import TABLE_S2_ROTATIONS
    R = TABLE_S2_ROTATIONS["camera"]
    K = [[2592.156, -0.2332, 309.047], [0, 2592.696, 236.166], [0, 0, 1]]
    with pytest.raises(ModelError, match=r"det = 0\.96"):
        DeviceModel(size=(640, 480), K=K, R=R, t=[4.866, -26.432, 847.611])
    dev = DeviceModel(size=(640, 480), K=K, R=R, t=[4.866, -26.432, 847.611], repair_rotation=True)
    assert len(dev.repairs) == 1 and "moved by 7.7" in dev.repairs[0]
    assert np.allclose(dev.R.T @ dev.R, np.eye(3), atol=1e-12)


def test_paper_s1_arctan_formulas_agree_with_ours_on_the_papers_system_only():
    for dev in default_system().devices().values():
        M = dev.R.T @ np.diag([1.0, -1.0, -1.0])
        np.testing.assert_allclose(paper_s1_angles(M), euler_xyz_from_matrix(M)[0], atol=1e-12)
    # a device rotated 120 deg about X: the bare arctan loses the quadrant, atan2 does not
    M = matrix_from_euler_xyz(np.radians([120.0, 10.0, 5.0]))
    assert not np.allclose(paper_s1_angles(M), np.radians([120.0, 10.0, 5.0]))
    np.testing.assert_allclose(euler_xyz_from_matrix(M)[0], np.radians([120.0, 10.0, 5.0]), atol=1e-12)


def _round_trip_error(dev, sheet):
    back = twin_to_device(device_to_twin(dev, sheet), kind=dev.kind)
    return (np.max(np.abs(back.K - dev.K)), np.max(np.abs(back.R - dev.R)), np.max(np.abs(back.t - dev.t)),
            np.max(np.abs(back.distortion - dev.distortion)) if dev.distortion.size else 0.0)


def test_forward_then_inverse_returns_the_builtin_system_to_1e9():
    s = default_system()
    back = from_twin(json.loads(json.dumps(to_twin(s))))  # through JSON text too
    for a, b in ((s.camera, back.camera), (s.projector, back.projector)):
        np.testing.assert_allclose(b.K, a.K, rtol=0, atol=1e-9)
        np.testing.assert_allclose(b.R, a.R, rtol=0, atol=1e-9)
        np.testing.assert_allclose(b.t, a.t, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(b.distortion, a.distortion)


rotations = st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(
    lambda q: np.linalg.norm(q) > 0.1).map(lambda q: _quat_to_matrix(np.asarray(q) / np.linalg.norm(q)))


def _quat_to_matrix(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


@settings(max_examples=300, deadline=None)
@given(R=rotations, t=st.lists(st.floats(-2000, 2000), min_size=3, max_size=3),
       f=st.tuples(st.floats(200, 20000), st.floats(200, 20000)), c=st.tuples(st.floats(-300, 900), st.floats(-300, 700)),
       skew=st.floats(-5, 5))
def test_round_trip_over_random_valid_rotations_and_intrinsics(R, t, f, c, skew):
    R, _ = np.linalg.qr(R)  # exact orthonormality from the quaternion within rounding
    R = R * np.sign(np.linalg.det(R))
    dev = DeviceModel(size=(640, 480), K=[[f[0], skew, c[0]], [0, f[1], c[1]], [0, 0, 1]], R=R, t=t)
    dK, dR, dt, _ = _round_trip_error(dev, GENERIC)
    assert dK < 1e-9 * max(f) and dR < 1e-9 and dt < 1e-9 * max(1.0, np.abs(t).max())


@pytest.mark.parametrize("beta_deg", [90.0, -90.0, 89.9999999, -89.99999999])
def test_gimbal_lock_is_solved_exactly(beta_deg):
    M = matrix_from_euler_xyz(np.radians([25.0, beta_deg, -40.0]))
    angles, lock = euler_xyz_from_matrix(M)
    np.testing.assert_allclose(matrix_from_euler_xyz(angles), M, atol=1e-12)
    R = (M @ np.diag([1.0, -1.0, -1.0])).T
    dev = DeviceModel(size=(640, 480), K=[[1000, 0, 320], [0, 1000, 240], [0, 0, 1]], R=R, t=[1, 2, 900])
    twin = device_to_twin(dev, GENERIC)
    assert ("gimbal_lock" in twin) == (abs(beta_deg) == 90.0)
    assert max(_round_trip_error(dev, GENERIC)[:3]) < 1e-9


@pytest.mark.parametrize("direction", ["down", "up"])
def test_device_looking_straight_down_or_up(direction):
    # camera axis +z_dev along world -Z (down) or +Z (up)
    R = np.diag([1.0, -1.0, -1.0]) if direction == "down" else np.eye(3)
    dev = DeviceModel(size=(640, 480), K=[[1000, 0, 320], [0, 1000, 240], [0, 0, 1]], R=R, t=[0, 0, 1000])
    twin = device_to_twin(dev, GENERIC)
    expected = [0.0, 0.0, 0.0] if direction == "down" else [180.0, 0.0, 0.0]
    np.testing.assert_allclose(np.abs(twin["rotation_euler_deg"]), expected, atol=1e-12)
    assert max(_round_trip_error(dev, GENERIC)[:3]) < 1e-9


@pytest.mark.parametrize("angle_deg", [179.0, 179.999999, 180.0])
def test_rotations_near_180_degrees(angle_deg):
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    R = matrix_from_rotvec(axis * math.radians(angle_deg))
    dev = DeviceModel(size=(640, 480), K=[[1000, 0, 320], [0, 1000, 240], [0, 0, 1]], R=R, t=[5, -3, 700])
    assert max(_round_trip_error(dev, GENERIC)[:3]) < 1e-9


def test_reflection_det_minus_one_is_refused_even_with_repair():
    R = np.diag([1.0, 1.0, -1.0])
    for repair in (False, True):
        with pytest.raises(ModelError, match="reflection"):
            DeviceModel(size=(640, 480), K=np.eye(3), R=R, repair_rotation=repair)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nan_and_inf_are_refused_everywhere(bad):
    K = [[1000, 0, 320], [0, 1000, 240], [0, 0, 1]]
    with pytest.raises(ModelError, match="non-finite"):
        DeviceModel(size=(640, 480), K=K, t=[0, bad, 1])
    R = np.eye(3)
    R[1, 2] = bad
    with pytest.raises(ModelError, match="non-finite"):
        DeviceModel(size=(640, 480), K=K, R=R)
    twin = device_to_twin(DeviceModel(size=(640, 480), K=K), GENERIC)
    twin["shift"][0] = bad
    with pytest.raises(TwinError, match="non-finite"):
        twin_to_device(twin)


def test_anisotropic_pixels_projector_fy_twice_fx():
    s = default_system()
    twin = device_to_twin(s.projector, DLP4500)
    assert twin["pixel_aspect"][0] / twin["pixel_aspect"][1] == pytest.approx(s.projector.fy / s.projector.fx)
    assert twin["focal_length_y_mm"] == pytest.approx(s.projector.fy * 6.8 / 1140)
    # and fy < fx maps to an aspect with y > 1 (Blender needs both >= 1)
    dev = DeviceModel(size=(640, 480), K=[[2000, 0, 320], [0, 1000, 240], [0, 0, 1]])
    tw = device_to_twin(dev, GENERIC)
    assert tw["pixel_aspect"] == [1.0, 2.0]
    assert max(_round_trip_error(dev, GENERIC)[:3]) < 1e-9


def test_skew_and_distortion_are_listed_as_not_representable_with_their_pixel_effect():
    s = default_system()
    cam = device_to_twin(s.camera, BASLER_ACA640_750UM)["not_representable"]
    # skew -0.2332 px times yd at the bottom corners, (479.5 - cy)/fy
    assert cam["skew_effect_px"] == pytest.approx(0.23324 * (479.5 - 236.1665) / 2592.696, rel=1e-4)
    assert 1.0 < cam["distortion_effect_px"] < 3.0
    prj = device_to_twin(s.projector, DLP4500)["not_representable"]
    assert prj["distortion_effect_px"] > 10  # k2 = 6.28 on the projector


@pytest.mark.parametrize("scale", [1e-9, 1e-3, 1e6, 1e9])
def test_tiny_and_huge_translations(scale):
    t = np.array([0.3, -0.7, 1.0]) * scale
    dev = DeviceModel(size=(640, 480), K=[[1000, 0.5, 320], [0, 1100, 240], [0, 0, 1]],
                      R=matrix_from_rotvec([0.1, 0.2, 2.9]), t=t)
    back = twin_to_device(device_to_twin(dev, GENERIC))
    np.testing.assert_allclose(back.t, t, rtol=1e-12, atol=1e-12)


def test_datasheet_of_the_wrong_size_is_refused():
    with pytest.raises(TwinError, match="differs from the datasheet"):
        device_to_twin(default_system().camera, DLP4500)
