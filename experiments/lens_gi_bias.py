"""The camera's thin lens and the interreflection together, Cycles against the twin: the
unit-frequency phase bias of depth of field *and* 4-bounce global illumination (issue 21 item 1).

Scenes (parity twin: ideal system, 160x120 camera, f = 648 px; 8 steps of vertical fringes at
f = 1; matte, albedo 0.8):

- ``ball-wall-lens``: the ``ball-wall`` scene of :mod:`experiments.gi_bias` (the 25.4 mm ball
  4.6 mm before a wall at z = -30 mm), the camera focused on the ball's front (camera depth
  822.2 mm, :data:`experiments.defocus_bias.FOCUS_MM`) with an 80 mm aperture: the wall (~877 mm)
  blurs into a ~4 px disc, the ball's outline (~848 mm) ~2 px.
- ``suzanne-wall-lens``: the held-out Suzanne mesh (``../shared/data/meshes/suzanne.obj``, 80 mm,
  facing the camera) 5 mm before the same wall, focused on its front-most vertex, same aperture.

Each renderer is compared with itself (as in gi_bias and defocus_bias): bias =
``wrap(phi_lens+gi - phi_pinhole,direct)``. Cycles: thin-lens depth of field (the driver's
``camera_dof``; the projector stays a pinhole: its textured spot light takes no radius, see
docs/synth.md) with ``bounces`` diffuse bounces, ``samples`` samples, one render per seed
(reference: circular mean of the seeds' maps; noise per seed: RMS of two seeds' difference /
sqrt 2), against its 1-sample pinhole direct frames. Ours: the thin lens
(``camera_defocus.samples`` aperture points) with :mod:`synth.effects.interreflection`, its
indirect light shared between the aperture points (``thin_lens = "shared"``) or per point
(``"exact"``); for contrast the old blur of the finished image with the interreflection, and
each effect alone.

Cycles frames are cached (``.npz``) in :func:`experiments.gi_bias.cache_dir`
(``$SLTWIN_GI_CACHE``), keyed by scene, aperture, focus, samples, bounces, seed, steps; the
pinhole direct frames share gi_bias's key (``<scene>_s1_b0_seed0_n8.npz``, the scene named
without its ``-lens`` suffix), so its cached ball-wall frames serve here.

Frames: world mm, the camera looks down -z at the origin from ~848 mm.
"""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from synth.effects.spec import Defocus, Effects, Interreflection
from synth.renderer.render import render
from synth.scenes.meshes import load_mesh
from synth.scenes.objects import Mesh, Plane
from synth.scenes.scene import Scene

from .defocus_bias import APERTURE_MM, FOCUS_MM
from .errors import ExperimentError
from .gi_bias import EXPOSURE, BiasScene, _rect, _setup, bias_map, bias_scene, cache_dir, cached_cycles

MESHES = Path(__file__).resolve().parents[2] / "shared" / "data" / "meshes"
SCENES = ("ball-wall-lens", "suzanne-wall-lens")
WALL_Z_MM = -30.0
#: Cycles' diffuse bounces
BOUNCES = 4


def _mesh_before_wall(name: str, file: str, size_mm: float, gap_mm: float, albedo: float) -> BiasScene:
    """Mesh ``file`` scaled to ``size_mm`` (largest extent), its file's +y up and +z towards the
    camera, its back ``gap_mm`` before the wall (z = -30 mm), centred on the optical axis."""
    V, F = load_mesh(MESHES / file)
    V = np.asarray(V, dtype=np.float64)
    V = (V - (V.max(0) + V.min(0)) / 2) * (size_mm / float((V.max(0) - V.min(0)).max()))
    V[:, 2] -= V[:, 2].min() - (WALL_Z_MM + gap_mm)
    Vw, Fw = _rect(np.array([0.0, 0.0, WALL_Z_MM]), np.eye(3), (600.0, 600.0), 4)
    return BiasScene(name, [Mesh(name.split("-")[0], np.eye(3), [0, 0, 0], V, F, albedo, True),
                            Plane("wall", np.eye(3), [0.0, 0.0, WALL_Z_MM], albedo, (600.0, 600.0))],
                     [(V, F, albedo, True), (Vw, Fw, albedo, False)],
                     f"{file} {size_mm:g} mm, {gap_mm:g} mm before a wall")


@functools.lru_cache(maxsize=4)
def lens_scene(name: str, *, albedo: float = 0.8) -> tuple[BiasScene, float]:
    """(scene, camera focus depth mm) of ``name`` (module docstring); cached, treat as read-only."""
    if name == "ball-wall-lens":
        return bias_scene("ball-wall", albedo=albedo), FOCUS_MM
    if name == "suzanne-wall-lens":
        if not (MESHES / "suzanne.obj").exists():
            raise ExperimentError(f"lens_scene: {MESHES / 'suzanne.obj'} is missing (../shared/data/meshes)")
        sc = _mesh_before_wall(name, "suzanne.obj", 80.0, 5.0, albedo)
        cam = _setup(8)[0].camera
        V = sc.meshes[0][0]
        depth = (V @ np.asarray(cam.R).T + np.asarray(cam.t))[:, 2]
        return sc, round(float(depth.min()), 1)
    raise ExperimentError(f"lens_scene: unknown scene {name!r} ({', '.join(SCENES)})")


def _key(name: str) -> str:
    return name.removesuffix("-lens")


def cycles_lens_images(name: str, *, samples: int, bounces: int, aperture_mm: float | None, seed: int = 0,
                       steps: int = 8, threads: int = 2, timeout: float = 3600, frames: int | None = None) -> dict:
    """Cycles' (K, H, W) linear images of ``name`` with depth of field (``aperture_mm`` None:
    pinhole) and ``bounces`` diffuse bounces; cached (module docstring). ``frames``: render only
    the first ``frames`` patterns, uncached (to time a frame)."""
    from synth.blender_twin import render_in_blender

    sc, focus = lens_scene(name)

    def rend():
        system, d_ref, patterns = _setup(steps)
        proj = np.stack([p.projector_image(system.projector.size, 0.5, 0.5) for p in patterns])[:frames]
        dof = None if aperture_mm is None else {"focus_mm": float(focus), "aperture_mm": float(aperture_mm)}
        return render_in_blender(system, sc.meshes, proj, exposure=EXPOSURE, reference_distance_mm=d_ref,
                                 threads=threads, samples=samples, bounces=bounces, seed=seed, camera_dof=dof,
                                 timeout=timeout)

    if frames is not None:
        return cached_cycles(None, rend)
    ap = "" if aperture_mm is None else f"_a{aperture_mm:g}_f{focus:g}"
    return cached_cycles(cache_dir() / f"{_key(name)}{ap}_s{samples}_b{bounces}_seed{seed}_n{steps}.npz", rend)


def cycles_lens_bias(name: str, *, samples: int, seeds=(0, 1), bounces: int = BOUNCES,
                     aperture_mm: float = APERTURE_MM, steps: int = 8) -> dict:
    """Cycles' bias map of depth of field + ``bounces`` bounces against its pinhole direct frames
    (experiments.gi_bias.seeds_bias: "bias", "maps", "direct", "seconds_per_frame")."""
    from .gi_bias import seeds_bias

    pin = cycles_lens_images(name, samples=1, bounces=0, aperture_mm=None, steps=steps)
    return seeds_bias(pin, [cycles_lens_images(name, samples=samples, bounces=bounces, aperture_mm=aperture_mm,
                                               seed=s, steps=steps) for s in seeds])


#: our models: (camera defocus samples (0: the old image blur, None: pinhole), interreflection thin_lens
#: mode or None for no interreflection)
MODELS = {
    "thin lens + interreflection, shared": (32, "shared"),
    "thin lens + interreflection, exact": (32, "exact"),
    "old image blur + interreflection": (0, "shared"),
    "thin lens alone (no interreflection)": (32, None),
    "interreflection alone (pinhole)": (None, "shared"),
}


def ours_lens_images(name: str, lens_samples: int | None, thin_lens: str | None, *, aperture_mm: float = APERTURE_MM,
                     bounces: int = 1, steps: int = 8):
    """Our (K, H, W) float64 linear images of ``name`` and the render result: the camera's thin
    lens with ``lens_samples`` aperture points (0: the old image blur; None: pinhole) and the
    interreflection (``bounces``) with ``thin_lens`` "shared" / "exact" (None: direct light only)."""
    system, d_ref, patterns = _setup(steps)
    sc, focus = lens_scene(name)
    dof = None if lens_samples is None else Defocus(aperture_mm, focus, 6, lens_samples)
    ir = None if thin_lens is None else Interreflection(bounces=bounces, thin_lens=thin_lens)
    eff = Effects(exposure=EXPOSURE, fringe_sampling="analytic", reference_distance_mm=d_ref,
                  camera_defocus=dof, interreflection=ir)
    res = render(Scene(system, sc.objects, patterns, eff), quantised=False)
    return res.images.numpy().astype(np.float64), res


def ours_lens_bias(name: str, lens_samples: int | None, thin_lens: str | None, *, direct=None, **kw) -> dict:
    """Our bias map of one model against our pinhole direct stack (``direct``: (images, result)
    of an earlier call, or None to render it): {"bias", "direct", "geometry", "seconds" (the
    model's render() total), "plan"}."""
    if direct is None:
        direct = ours_lens_images(name, None, None, steps=kw.get("steps", 8))
    imgs, res = ours_lens_images(name, lens_samples, thin_lens, **kw)
    return {"bias": bias_map(imgs, direct[0]), "direct": direct[0], "geometry": direct[1].geometry,
            "seconds": res.timings["total"], "plan": res.plan}
