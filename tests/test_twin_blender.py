"""The twin mapping's acceptance test: Blender's own cameras, built from our exported script, put
3D points on the pixels our pinhole model gives (skew and distortion set to zero)."""
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from calib import default_system
from twin_mapping.blender_export import write_blender_script
from twin_mapping.twin import to_twin

pytestmark = pytest.mark.blender
DRIVER = Path(__file__).with_name("blender_projection_driver.py")
TOL_PX = 1e-3


def _points_in_view(device, n, rng):
    """World points (n,3) that the ideal pinhole of ``device`` sees at uniform random pixels."""
    ideal = device.without_skew_and_distortion()
    q = rng.uniform([-0.5, -0.5], np.array(device.size) - 0.5, size=(n, 2))
    rays, ok = ideal.unproject(q)
    assert ok.all()
    X_dev = rays * rng.uniform(400.0, 1500.0, size=(n, 1))
    return (X_dev - ideal.t) @ ideal.R, q


@pytest.fixture(scope="module")
def blender_projection(tmp_path_factory):
    if importlib.util.find_spec("bpy") is None:
        pytest.skip("bpy (Blender as a module) is not installed; `make test` installs it")
    tmp = tmp_path_factory.mktemp("blender")
    system = default_system()
    twin = to_twin(system)
    script = write_blender_script(twin, tmp / "scene.py")
    rng = np.random.default_rng(7)
    points, expected = {}, {}
    for kind, dev in system.devices().items():
        X, q = _points_in_view(dev, 300, rng)
        points[kind] = X.tolist()
        expected[kind] = q
    (tmp / "points.json").write_text(json.dumps(points))
    run = subprocess.run([sys.executable, str(DRIVER), str(script), str(tmp / "points.json"), str(tmp / "out.json")],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    return twin, expected, json.loads((tmp / "out.json").read_text())


@pytest.mark.parametrize("kind", ["camera", "projector"])
def test_blender_camera_matrices_project_points_onto_our_pinhole_pixels(blender_projection, kind):
    twin, expected, out = blender_projection
    err = np.linalg.norm(np.asarray(out[kind]["q_matrices"]) - expected[kind], axis=1)
    print(f"{kind}: Blender matrices vs pinhole: max {err.max():.2e} px, rms {np.sqrt(np.mean(err**2)):.2e} px")
    assert err.max() < TOL_PX


@pytest.mark.parametrize("kind", ["camera", "projector"])
def test_blender_world_to_camera_view_agrees_too(blender_projection, kind):
    twin, expected, out = blender_projection
    err = np.linalg.norm(np.asarray(out[kind]["q_world_to_camera_view"]) - expected[kind], axis=1)
    assert err.max() < TOL_PX


def test_blender_reads_back_the_twin_parameters(blender_projection):
    twin, _, out = blender_projection
    for kind in ("camera", "projector"):
        b, t = out[kind], twin[kind]
        assert b["resolution"] == t["resolution"]
        np.testing.assert_allclose(b["lens"], t["focal_length_mm"], rtol=1e-6)
        np.testing.assert_allclose(b["sensor_width"], t["sensor_size_mm"][0], rtol=1e-6)
        np.testing.assert_allclose(b["shift"], t["shift"], atol=1e-7)
        np.testing.assert_allclose(b["pixel_aspect"], t["pixel_aspect"], rtol=1e-6)
        np.testing.assert_allclose(np.asarray(b["matrix_world"])[:3, 3] * 1000, t["location_mm"], atol=1e-3)
    light = out["projector_light"]
    assert light["type"] == "SPOT" and light["shadow_soft_size"] == 0.0
    np.testing.assert_allclose(light["matrix_world"], out["projector"]["matrix_world"], atol=1e-7)
