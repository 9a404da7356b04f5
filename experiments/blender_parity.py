"""Our renderer against Blender Cycles on the same twin (plane or ball): images and decoded phase.

``parity(kind, scale, steps, frequency)`` renders ``steps`` phase-shifted vertical fringes with
both, and returns the mean absolute difference in 8-bit levels and the RMS difference of the
N-step phase over pixels lit in both. Our side samples the pattern image bilinearly, as Blender's
linear texture lookup does.
"""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import torch

from synth.blender_twin import render_in_blender
from synth.effects.spec import Effects
from synth.renderer.render import render
from synth.scenes.meshes import sphere_mesh
from synth.scenes.objects import Plane, Sphere
from synth.scenes.scene import DEFAULT_BALL_RADIUS_MM, Scene, ideal_system
from synth.scenes.sequence import phase_sequence


def parity_system(scale: int = 4):
    """The default system, ideal (no skew/distortion), square camera pixels, camera reduced."""
    from calib import default_system
    from calib.system import SystemModel

    s = ideal_system(default_system())
    return SystemModel(downscaled_camera(s.camera, scale, square_pixels=True), s.projector, dict(s.meta))


def downscaled_camera(cam, scale: int, *, square_pixels: bool = False):
    """The camera with its image reduced ``scale`` times over the same field of view (pixel centres
    at integer coordinates); ``square_pixels`` sets fy = fx (Blender's cameras have square pixels)."""
    K = np.array(cam.K)
    K[0, :] /= scale
    K[1, :] /= scale
    K[0, 2] = (cam.cx + 0.5) / scale - 0.5
    K[1, 2] = (cam.cy + 0.5) / scale - 0.5
    if square_pixels:
        K[1, 1] = K[0, 0]
    return cam.with_(size=(cam.width // scale, cam.height // scale), K=K)


def _phase_and_modulation(stack):
    """N-step wrapped phase and modulation B' of ``I_n = A' + B' cos(phi - 2 pi n / N)`` (unwrap's
    least-squares formula), each (H,W) float64."""
    from unwrap.phase_shift import wrapped_phase

    w = wrapped_phase(np.asarray(stack, dtype=np.float64), saturation=None, fill_invalid=False)
    return np.asarray(w.phase), np.asarray(w.B)


def parity(kind: str = "plane", scale: int = 4, steps: int = 12, frequency: float = 48, threads: int = 2,
           exposure: float = 0.8, albedo: float = 0.8, python: str | None = None, camera_defocus=None,
           samples: int = 1) -> dict:
    """Render both and compare (see the module docstring). ``camera_defocus`` (an
    ``effects.Defocus``) turns on our camera defocus and Blender's thin-lens depth of field
    (circular aperture of the same diameter, same focus depth); it needs ``samples`` > 1 in
    Blender. The result also holds the N-step modulation ``amp`` of each side (H,W)."""
    system = parity_system(scale)
    d_ref = float(np.linalg.norm(system.projector.center_world))
    eff = Effects(exposure=exposure, fringe_sampling="bilinear", reference_distance_mm=d_ref,
                  camera_defocus=camera_defocus)
    if kind == "plane":
        obj = Plane("plane", np.eye(3), [0, 0, 0], albedo)
        big = 3000.0
        meshes = [(np.array([[-big, -big, 0], [big, -big, 0], [0, big, 0]]), np.array([[0, 1, 2]]), albedo, False)]
    else:
        obj = Sphere("ball", np.eye(3), [0, 0, 0], albedo, DEFAULT_BALL_RADIUS_MM)
        V, F = sphere_mesh(DEFAULT_BALL_RADIUS_MM, 512, 256)
        meshes = [(V, F, albedo, True)]
    patterns = phase_sequence(("v",), (frequency,), steps)
    scene = Scene(system, [obj], patterns, eff)
    t0 = time.perf_counter()
    ours = render(scene, quantised=False)
    ours_s = time.perf_counter() - t0
    proj_imgs = np.stack([p.projector_image(system.projector.size, eff.A, eff.B) for p in patterns])
    bl = render_in_blender(system, meshes, proj_imgs, exposure=exposure, reference_distance_mm=d_ref,
                           threads=threads, samples=samples, python=python,
                           camera_dof=None if camera_defocus is None else
                           {"focus_mm": camera_defocus.focus_mm, "aperture_mm": camera_defocus.aperture_mm})
    a = ours.images.numpy().astype(np.float64)
    b = bl["images"]
    lit = ours.geometry.lit.reshape(a.shape[1:]).numpy()
    # away from the silhouette: the ball's rim pixels differ by where the facets end
    inner = lit.copy()
    inner[1:-1, 1:-1] &= lit[:-2, 1:-1] & lit[2:, 1:-1] & lit[1:-1, :-2] & lit[1:-1, 2:]
    (phi_a, amp_a), (phi_b, amp_b) = _phase_and_modulation(a), _phase_and_modulation(b)
    inner &= amp_b > 0.05 * 0.1  # Blender also lit there
    mad = float(np.mean(np.abs(a - b)[:, inner]) * 255)
    dphi = np.angle(np.exp(1j * (phi_a - phi_b)))[inner]
    return {"kind": kind, "size": system.camera.size, "pixels": int(inner.sum()), "mad_8bit": mad,
            "phase_rms_rad": float(np.sqrt(np.mean(dphi ** 2))), "phase_max_rad": float(np.abs(dphi).max()),
            "ours_seconds": ours_s, "blender_seconds_per_frame": float(np.mean(bl["seconds_per_frame"])),
            "blender_wall_seconds": bl["wall_seconds"], "ours_images": a, "blender_images": b, "mask": inner,
            "amp_ours": amp_a, "amp_blender": amp_b, "geometry": ours.geometry}
