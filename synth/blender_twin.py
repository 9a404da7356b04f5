"""Render the same scene with Blender Cycles (CPU), in a SUBPROCESS: the toolkit never imports bpy
itself. Used by the parity tests and the benchmark.

One Blender scene builder serves the whole toolkit: the twin's exported scene script
(``twin_mapping.blender_export``, body ``twin_mapping/blender_template.py``: camera, projector as
a textured zero-radius SPOT light per BLENDER-NOTES, Cycles on the CPU with 1 point-sampled
path per pixel, direct light only, view transform Raw, dither 0), and one driver runs it
(``twin_mapping/blender_driver.py`` through :func:`twin_mapping.blender_run.run_in_blender`);
its ``render`` job adds only what parity needs: the Lambertian surfaces, the pattern image on
the spot light, the sample count, 16-bit linear PNG output and, optionally, the camera's depth
of field. Skew and distortion are not representable in Blender: give an ideal system
(``synth.ideal_system``); anything else is refused.

Radiometry: the spot is a point source of P/(4 pi) W/sr, so a Lambertian surface of albedo rho
shows ``rho/pi * P/(4 pi) * cos / d^2``; ``P = 4 pi^2 exposure d_ref^2`` (metres) matches our
``exposure * rho * cos * (d_ref/d)^2``.
"""
from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path

import numpy as np

from twin_mapping.blender_run import blender_available, run_in_blender  # noqa: F401  (kept name)

from .errors import SynthError


def blender_twin(system) -> dict:
    """The twin dictionary (``twin_mapping.to_twin``) of an ideal system, for rendering.

    Only the focal length / sensor width ratio matters to a render, so each device gets a
    nominal pitch making its sensor 36 mm wide (Blender's default; keeps Blender's lens >= 1 mm
    for any image size)."""
    from twin_mapping.datasheets import Datasheet
    from twin_mapping.twin import to_twin

    for dev in (system.camera, system.projector):
        if dev.skew != 0 or np.any(dev.distortion):
            raise SynthError(f"{dev.kind}: skew and lens distortion cannot be represented in Blender; "
                             "render an ideal system (synth.ideal_system)")
    sheets = {kind: Datasheet(f"nominal {kind} (36 mm sensor width)", tuple(dev.size),
                              (36000.0 / dev.size[0],) * 2)
              for kind, dev in (("camera", system.camera), ("projector", system.projector))}
    return to_twin(system, sheets)


def render_in_blender(system, meshes, patterns: np.ndarray, *, exposure: float, reference_distance_mm: float,
                      threads: int = 2, samples: int = 1, camera_dof: dict | None = None,
                      python: str | None = None, workdir=None, timeout: float = 600, subsurface: dict | None = None,
                      bounces: int = 0, seed: int | None = None) -> dict:
    """Render ``patterns`` (K, H_p, W_p) in [0, 1] with Cycles in a subprocess.

    ``meshes``: list of ``(vertices_world (V,3) mm, faces (F,3), albedo, smooth)``.
    ``subsurface``: None or ``{"weight", "radius_mm", "method"}`` for every mesh (Cycles' subsurface
    scattering; needs ``bounces`` > 0 and ``samples`` > 1).
    ``camera_dof``: None (pinhole) or ``{"focus_mm": camera depth in focus, "aperture_mm":
    aperture diameter}`` (thin lens, circular aperture; needs ``samples`` > 1 to converge).
    ``seed``: Cycles' sampling seed (None: Blender's default, 0).
    RETURNED VALUE: {"images": (K,H,W) float64 linear values in [0, 1] (16-bit PNG / 65535),
    "seconds_per_frame": list of Cycles render times, "wall_seconds": whole subprocess}.
    """
    import cv2
    from twin_mapping.blender_export import write_blender_script

    tmp = Path(workdir or tempfile.mkdtemp(prefix="synth_blender_"))
    tmp.mkdir(parents=True, exist_ok=True)
    script = write_blender_script(blender_twin(system), tmp / "twin_scene.py")
    np.save(tmp / "patterns.npy", np.asarray(patterns, dtype=np.float32))
    cfg = {"power_w": 4 * math.pi ** 2 * exposure * (reference_distance_mm / 1000.0) ** 2,
           "threads": int(threads), "samples": int(samples), "camera_dof": camera_dof,
           "projector_size": list(system.projector.size), "patterns": str(tmp / "patterns.npy"), "out": str(tmp),
           "bounces": int(bounces), "seed": None if seed is None else int(seed),
           "objects": [{"vertices": np.asarray(V).tolist(), "faces": np.asarray(F).tolist(), "albedo": float(a),
                        "smooth": bool(s), "subsurface": subsurface} for V, F, a, s in meshes]}
    wall = run_in_blender("render", script, cfg, tmp, python=python, timeout=timeout)
    imgs = np.stack([cv2.imread(str(tmp / f"{k:03d}.png"), cv2.IMREAD_UNCHANGED).astype(np.float64) / 65535.0
                     for k in range(len(patterns))])
    times = json.loads((tmp / "times.json").read_text())["times"]
    return {"images": imgs, "seconds_per_frame": times, "wall_seconds": wall}
