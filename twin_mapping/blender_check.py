"""Check a twin inside Blender itself (needs the ``bpy`` module; runs it in a subprocess).

The exported scene script is run by a Python that has bpy; Blender's own cameras (matrix_world,
calc_matrix_camera, and world_to_camera_view) project random 3D points, which must land on the
pixels of our ideal pinhole model (skew and distortion set to zero). bpy is never imported in
this process: the toolkit does not depend on it.
"""
from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from calib.system import SystemModel

from .blender_export import write_blender_script
from .blender_run import run_in_blender
from .twin import to_twin


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
    twin = twin or to_twin(system)
    tmp = Path(workdir) if workdir else Path(tempfile.mkdtemp(prefix="sltwin-blender-"))
    tmp.mkdir(parents=True, exist_ok=True)
    script = write_blender_script(twin, tmp / "twin_scene.py")
    rng = np.random.default_rng(seed)
    points, expected = {}, {}
    for kind, dev in system.devices().items():
        X, q = points_in_view(dev, n_points, rng)
        points[kind], expected[kind] = X.tolist(), q
    run_in_blender("check", script, {"points": points, "out": str(tmp / "blender_out.json"),
                                     "save_blend": str(save_blend) if save_blend else None}, tmp, python=python)
    out = json.loads((tmp / "blender_out.json").read_text())
    result = {"readback": out}
    for kind in ("camera", "projector"):
        e1 = np.linalg.norm(np.asarray(out[kind]["q_matrices"]) - expected[kind], axis=1)
        e2 = np.linalg.norm(np.asarray(out[kind]["q_world_to_camera_view"]) - expected[kind], axis=1)
        result[kind] = {"n_points": n_points, "max_px": float(e1.max()), "rms_px": float(np.sqrt(np.mean(e1 ** 2))),
                        "max_px_world_to_camera_view": float(e2.max())}
    return result
