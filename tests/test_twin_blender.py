"""The twin mapping's acceptance test: Blender's own cameras, built from our exported script, put
3D points on the pixels our pinhole model gives (skew and distortion set to zero)."""
import numpy as np
import pytest

from calib import default_system
from twin_mapping.blender_check import check_twin_in_blender
from twin_mapping.blender_run import blender_available as bpy_available

pytestmark = pytest.mark.blender
TOL_PX = 3e-4
"""Blender's float32 matrices against our float64 pinhole: measured max 4.8e-5 px (camera), 7.7e-5 px
(projector, fy = 2 fx); README."""
TOL_PX_WORLD_TO_CAMERA_VIEW = 1e-3
"""bpy_extras' world_to_camera_view (float32 NDC): measured max 9.8e-5 px (camera), 2.5e-4 px (projector)."""


@pytest.fixture(scope="module")
def blender_result(tmp_path_factory):
    if not bpy_available():
        pytest.skip("bpy (Blender as a module) is not installed; `make test` installs it")
    return check_twin_in_blender(default_system(), tmp_path_factory.mktemp("blender"), n_points=300, seed=7)


@pytest.mark.parametrize("kind", ["camera", "projector"])
def test_blender_camera_matrices_project_points_onto_our_pinhole_pixels(blender_result, kind):
    r = blender_result[kind]
    print(f"{kind}: Blender matrices vs pinhole: max {r['max_px']:.2e} px, rms {r['rms_px']:.2e} px")
    assert r["n_points"] == 300 and r["max_px"] < TOL_PX


@pytest.mark.parametrize("kind", ["camera", "projector"])
def test_blender_world_to_camera_view_agrees_too(blender_result, kind):
    assert blender_result[kind]["max_px_world_to_camera_view"] < TOL_PX_WORLD_TO_CAMERA_VIEW


def test_blender_reads_back_the_twin_parameters(blender_result):
    from twin_mapping.twin import to_twin

    twin = to_twin(default_system())
    out = blender_result["readback"]
    for kind in ("camera", "projector"):
        b, t = out[kind], twin[kind]
        assert b["resolution"] == t["resolution"]
        # Blender stores these as float32
        np.testing.assert_allclose(b["lens"], t["focal_length_mm"], rtol=1e-6)
        np.testing.assert_allclose(b["sensor_width"], t["sensor_size_mm"][0], rtol=1e-6)
        np.testing.assert_allclose(b["shift"], t["shift"], atol=1e-7)
        np.testing.assert_allclose(b["pixel_aspect"], t["pixel_aspect"], rtol=1e-6)
        np.testing.assert_allclose(np.asarray(b["matrix_world"])[:3, 3] * 1000, t["location_mm"], atol=1e-3)
    light = out["projector_light"]
    assert light["type"] == "SPOT" and light["shadow_soft_size"] == 0.0
    np.testing.assert_allclose(light["matrix_world"], out["projector"]["matrix_world"], atol=1e-7)


def test_a_wrong_mapping_would_fail_this_check(tmp_path):
    """Sanity of the check itself: a principal point off by 1 px is seen by Blender."""
    if not bpy_available():
        pytest.skip("bpy not installed")
    from twin_mapping.twin import to_twin

    system = default_system()
    twin = to_twin(system)
    twin["camera"]["shift"][0] += 1.0 / 640  # 1 px
    r = check_twin_in_blender(system, tmp_path, n_points=20, twin=twin)
    assert r["camera"]["max_px"] > 0.9
