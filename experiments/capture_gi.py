"""The unit-phase bias that interreflection makes on a real capture's own geometry, rendered by the
twin's physically based interreflection (synth.effects.interreflection), against the bias the
capture shows (experiments.pixel_twin.unit_phase_bias).

Geometry: the capture's absolute phase of its top frequency (reference orders where there are
some, the 5x5 plane through the corrected orders: :func:`experiments.pixel_twin._absolute_top`)
triangulated with the capture's calibration (``calib.triangulate.points_from_phase``, distortion
aware) into a world point per camera pixel; every ``stride``-th pixel becomes a vertex, a 2x2
cell two triangles unless an edge is longer than ``max_edge_px`` pixel footprints (a depth jump:
an occlusion edge is not bridged). Only what the camera sees is there: surfaces the projector
lights but the camera does not (inside the eye sockets, the table) are missing, so the indirect
light is a lower bound.

Render: the calibration's system (camera reduced ``scale`` times, the projector as is), one
Lambertian mesh of ``albedo``, vertical fringes at the unit frequency in the capture's step count,
noise-free, direct only and with ``Interreflection(bounces, patch_px)``; bias =
``wrap(phi_gi - phi_direct)`` (rad), brought to the capture's pixels by bilinear resampling.

Frames: SLStudio's world is its camera (mm).
"""
from __future__ import annotations

import time

import numpy as np

from .errors import ExperimentError


def capture_mesh(real_file, system, *, stride: int = 2, max_edge_px: float = 4.0, orientation: str = "v"):
    """(V (n, 3) world mm, F (m, 3)) of the capture's surface (module docstring)."""
    from calib.triangulate import points_from_phase

    from .pixel_twin import _absolute_top

    Phi, r, ok, _, _, freqs = _absolute_top(real_file, orientation)
    pts, q, good = points_from_phase(system, np.where(ok, Phi - r, np.nan), freqs[-1], orientation)
    H, W = Phi.shape
    X = np.full((H, W, 3), np.nan)
    X[np.rint(q[:, 1]).astype(int), np.rint(q[:, 0]).astype(int)] = np.where(good[:, None], pts, np.nan)
    Xs = X[::stride, ::stride]
    h, w = Xs.shape[:2]
    V = Xs.reshape(-1, 3)
    fin = np.all(np.isfinite(V), axis=1)
    if fin.sum() < 3:
        raise ExperimentError(f"{real_file}: no surface to mesh")
    foot = float(np.median(V[fin, 2])) / float(system.camera.fx)          # mm per camera pixel at the surface
    idx = np.arange(h * w).reshape(h, w)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = []
    for tri in ((a, d, b), (a, c, d)):                # wound to face the camera (world = camera, +z away)
        T = np.stack(tri, axis=1)
        keep = fin[T].all(axis=1)
        edge = np.max([np.linalg.norm(np.nan_to_num(V[T[:, i]] - V[T[:, (i + 1) % 3]], nan=np.inf), axis=1)
                       for i in range(3)], axis=0)
        faces.append(T[keep & (edge < max_edge_px * stride * foot)])
    F = np.concatenate(faces)
    used = np.unique(F)
    remap = np.full(len(V), -1, np.int64)
    remap[used] = np.arange(used.size)
    return V[used], remap[F]


def interreflection_bias(real_file, system_file, *, stride: int = 2, scale: int = 2, albedo: float = 0.8,
                         bounces: int = 1, patch_px: float = 32.0, steps: int = 3, orientation: str = "v") -> dict:
    """The rendered unit-phase bias of interreflection on the capture's geometry (module docstring).

    RETURNED VALUE: {"bias" (H, W) rad at the capture's pixels (0 where the render sees nothing),
    "lit" (H, W) bool, "seconds" of the interreflection render, "plan" its plan line, "mesh"
    (vertices, faces)}."""
    import cv2

    from calib import load_system
    from calib.system import SystemModel
    from synth.effects.spec import Effects, Interreflection
    from synth.renderer.render import render
    from synth.scenes.objects import Mesh
    from synth.scenes.scene import Scene
    from synth.scenes.sequence import phase_sequence
    from unwrap.phase_shift import wrapped_phase

    from .blender_parity import downscaled_camera

    system = load_system(system_file)
    V, F = capture_mesh(real_file, system, stride=stride, orientation=orientation)
    cam = downscaled_camera(system.camera, scale) if scale > 1 else system.camera
    scene_sys = SystemModel(cam, system.projector, dict(system.meta))
    mesh = Mesh("capture", np.eye(3), [0.0, 0.0, 0.0], V, F, albedo, smooth=True)
    pats = phase_sequence((orientation,), (1,), steps)
    imgs, plan, secs = {}, "", 0.0
    for name, ir in (("direct", None), ("gi", Interreflection(bounces=bounces, patch_px=patch_px))):
        t = time.perf_counter()
        res = render(Scene(scene_sys, [mesh], pats, Effects(exposure=0.5, interreflection=ir)), quantised=False)
        imgs[name] = res.images.numpy().astype(np.float64)
        if ir is not None:
            secs = time.perf_counter() - t
            plan = next((ln for ln in res.plan if ln.startswith("interreflection")), "")
    ph = {k: np.asarray(wrapped_phase(v).phase) for k, v in imgs.items()}
    small = np.angle(np.exp(1j * (ph["gi"] - ph["direct"])))
    lit = np.isfinite(small) & (imgs["direct"].mean(0) > 1e-4)
    W, H = system.camera.size
    bias = cv2.resize(np.where(lit, small, 0.0), (W, H), interpolation=cv2.INTER_LINEAR)
    lit_full = cv2.resize(lit.astype(np.float32), (W, H), interpolation=cv2.INTER_NEAREST) > 0.5
    return {"bias": np.where(lit_full, bias, 0.0), "lit": lit_full, "seconds": secs, "plan": plan, "mesh": (V, F)}


def compare_bias(rendered, lit, measured: dict, window: int) -> dict:
    """Correlation and amplitude of a rendered bias map (H, W) rad against
    :func:`experiments.pixel_twin.unit_phase_bias`'s result ``measured`` (same ``window``), the
    rendered map averaged the same way over the same labelled pixels. ``scale``: the least-squares
    factor measured ~ scale x rendered (1: the rendered amplitude is the capture's)."""
    import cv2

    lab = measured["labelled"]
    n = cv2.boxFilter(lab.astype(np.float64), -1, (window, window), normalize=False)
    s = cv2.boxFilter(np.where(lab, rendered, 0.0), -1, (window, window), normalize=False)
    avg = np.where(n > 0, s / np.maximum(n, 1.0), 0.0)
    m = lab & lit & (n > window * window / 4.0)
    a, c = measured["bias"][m], avg[m]
    if m.sum() < 100 or c.std() == 0 or a.std() == 0:
        raise ExperimentError("compare_bias: fewer than 100 pixels, or a constant map")
    k = float(np.dot(a, c) / np.dot(c, c))
    return {"pixels": int(m.sum()), "correlation": float(np.corrcoef(a, c)[0, 1]),
            "rms_measured": float(np.sqrt(np.mean(a ** 2))), "rms_rendered": float(np.sqrt(np.mean(c ** 2))),
            "scale": k, "diff_rms_scaled": float(np.sqrt(np.mean((a - k * c) ** 2)))}
