"""Check a twin inside Blender itself (needs the ``bpy`` module; runs it in a subprocess).

The exported scene script is run by a Python that has bpy; Blender's own cameras (matrix_world,
calc_matrix_camera, and world_to_camera_view) project random 3D points, which must land on the
pixels of our ideal pinhole model (skew and distortion set to zero). bpy is never imported in
this process: the toolkit does not depend on it.
"""
from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import tempfile
from importlib import resources
from pathlib import Path

import numpy as np

from calib.system import SystemModel

from .blender_export import write_blender_script
from .errors import TwinError
from .twin import to_twin


def bpy_available(python: str = sys.executable) -> bool:
    if python == sys.executable:
        return importlib.util.find_spec("bpy") is not None
    return subprocess.run([python, "-c", "import bpy"], capture_output=True).returncode == 0


def points_in_view(device, n: int, rng, depth_mm=(400.0, 1500.0)):
    """World points (n,3) seen by the ideal pinhole of ``device`` at uniform random pixels (n,2)."""
    ideal = device.without_skew_and_distortion()
    q = rng.uniform([-0.5, -0.5], np.array(device.size) - 0.5, size=(n, 2))
    rays, _ = ideal.unproject(q)
    X_dev = rays * rng.uniform(*depth_mm, size=(n, 1))
    return (X_dev - ideal.t) @ ideal.R, q


def check_twin_in_blender(system: SystemModel, workdir=None, *, n_points: int = 300, seed: int = 0,
                          twin: dict | None = None, python: str = sys.executable, save_blend=None) -> dict:
    """Project ``n_points`` per device through Blender's cameras; return errors in pixels.

    RETURNED VALUE: ``{"camera": {...}, "projector": {...}, "readback": {...}}`` where each device
    entry holds ``max_px``/``rms_px`` for the matrix route and ``max_px_world_to_camera_view``.
    """
    if not bpy_available(python):
        raise TwinError("Blender as a Python module (bpy) is not installed in this Python; "
                        "`make test` installs it (pip install bpy==4.5.15)")
    twin = twin or to_twin(system)
    tmp = Path(workdir) if workdir else Path(tempfile.mkdtemp(prefix="sltwin-blender-"))
    tmp.mkdir(parents=True, exist_ok=True)
    script = write_blender_script(twin, tmp / "twin_scene.py")
    rng = np.random.default_rng(seed)
    points, expected = {}, {}
    for kind, dev in system.devices().items():
        X, q = points_in_view(dev, n_points, rng)
        points[kind], expected[kind] = X.tolist(), q
    (tmp / "points.json").write_text(json.dumps(points))
    driver = resources.files("twin_mapping").joinpath("blender_check_driver.py")
    cmd = [python, str(driver), str(script), str(tmp / "points.json"), str(tmp / "blender_out.json")]
    if save_blend:
        cmd.append(str(save_blend))
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    if run.returncode != 0:
        raise TwinError(f"the Blender check failed:\n{run.stderr[-2000:]}")
    out = json.loads((tmp / "blender_out.json").read_text())
    result = {"readback": out}
    for kind in ("camera", "projector"):
        e1 = np.linalg.norm(np.asarray(out[kind]["q_matrices"]) - expected[kind], axis=1)
        e2 = np.linalg.norm(np.asarray(out[kind]["q_world_to_camera_view"]) - expected[kind], axis=1)
        result[kind] = {"n_points": n_points, "max_px": float(e1.max()), "rms_px": float(np.sqrt(np.mean(e1 ** 2))),
                        "max_px_world_to_camera_view": float(e2.max())}
    return result
