"""The unit-frequency phase bias that interreflections make, Cycles against the twin.

Scenes like real ones (a ball a few mm before a wall, a concave corner), rendered on the parity
twin (:func:`experiments.blender_parity.parity_system`: ideal system, 160x120 camera) by Blender Cycles with
``bounces`` diffuse bounces and with direct light only, and by our renderer with and without
:mod:`synth.effects.interreflection`. Each renderer is compared with *itself*: the bias map is

    bias(x) = wrap(phi_gi(x) - phi_direct(x))        (rad, at the unit frequency, N steps)

so radiometric scale and each renderer's conventions cancel; what is compared is what the
indirect light does to the phase. Cycles' own noise is measured by rendering the GI frames with
two sampling seeds: the RMS of ``bias_seed0 - bias_seed1`` over sqrt 2 is the noise of one map.

Cycles maps are cached as ``.npz`` in ``cache_dir`` (never inside the repository by default:
``$SLTWIN_GI_CACHE`` or the system's temporary folder), keyed by scene, samples, bounces, seed.

Frames: world mm; the camera looks down -z at the world origin from ~836 mm (parity system).
"""
from __future__ import annotations

import functools
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from synth.effects.spec import Effects, Interreflection
from synth.renderer.render import render
from synth.scenes.meshes import grid_mesh, load_mesh, sphere_mesh
from synth.scenes.objects import Mesh, Plane, Sphere
from synth.scenes.scene import DEFAULT_BALL_RADIUS_MM, Scene
from synth.scenes.sequence import phase_sequence

from .blender_parity import parity_system
from .errors import ExperimentError

#: Fringe periods of the "fine" pattern the bias is expressed in (the issue's x64 fringes).
FINE_PERIODS = 64
EXPOSURE = 0.8


@dataclass
class BiasScene:
    """One scene for both renderers: ``objects`` (ours) and ``meshes`` ((V, F, albedo, smooth)
    world mm, Cycles)."""

    name: str
    objects: list
    meshes: list
    note: str


def _rect(center, R, size, n=8):
    """A rectangle (object frame z = 0, ``size`` (w, h) mm, n x n cells) in the world: (V, F)."""
    w, h = size
    V, F = grid_mesh(np.linspace(-w / 2, w / 2, n + 1), np.linspace(-h / 2, h / 2, n + 1), np.zeros((n + 1, n + 1)))
    return V @ np.asarray(R).T + np.asarray(center), F


def _rot_y(deg):
    a = math.radians(deg)
    return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])


@functools.lru_cache(maxsize=8)
def bias_scene(name: str, *, albedo: float = 0.8) -> BiasScene:
    """The scenes of the comparison:

    - ``ball-wall``: a 25.4 mm radius ball at the origin, a wall (plane z = -30 mm, 600 x 600 mm)
      4.6 mm behind it; both matte, ``albedo``.
    - ``corner``: a concave 90 degree dihedral (two 120 x 160 mm walls folded along the world y
      axis, opening towards the camera), as a box corner.
    - ``bunny-wall``: the Stanford bunny (80 mm) 5 mm before the wall (meshes: self-occlusion).

    Cached (the same objects are returned again: treat them as read-only)."""
    wall_R, wall_t, wall_size = np.eye(3), np.array([0.0, 0.0, -30.0]), (600.0, 600.0)
    if name == "ball-wall":
        r = DEFAULT_BALL_RADIUS_MM
        V, F = sphere_mesh(r, 512, 256)
        Vw, Fw = _rect(wall_t, wall_R, wall_size, 4)
        return BiasScene(name, [Sphere("ball", np.eye(3), [0, 0, 0], albedo, r),
                                Plane("wall", wall_R, wall_t, albedo, wall_size)],
                         [(V, F, albedo, True), (Vw, Fw, albedo, False)],
                         "ball r 25.4 mm, 4.6 mm before a wall")
    if name == "corner":
        L, Hh = 120.0, 160.0
        objs, meshes = [], []
        for side, deg in (("left", 45.0), ("right", -45.0)):
            R = _rot_y(deg)
            d = R[:, 0] * math.copysign(1.0, R[2, 0])  # from the fold outwards, towards the camera (+z)
            c = L / 2 * d
            objs.append(Plane(side, R, c, albedo, (L, Hh)))
            meshes.append((*_rect(c, R, (L, Hh), 16), albedo, False))
        return BiasScene(name, objs, meshes, "concave 90 deg corner, 120 x 160 mm walls")
    if name == "bunny-wall":
        V, F = load_mesh(Path(__file__).resolve().parents[2] / "shared/data/meshes/stanford-bunny.obj")
        V = np.asarray(V, dtype=np.float64)
        V = (V - (V.max(0) + V.min(0)) / 2) * (80.0 / float((V.max(0) - V.min(0)).max()))
        V = V @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]]).T  # y-up file -> facing the camera (+z)
        V[:, 2] -= V[:, 2].min() + 25.0  # 5 mm before the wall at z = -30
        Vw, Fw = _rect(wall_t, wall_R, wall_size, 4)
        return BiasScene(name, [Mesh("bunny", np.eye(3), [0, 0, 0], V, F, albedo, True),
                                Plane("wall", wall_R, wall_t, albedo, wall_size)],
                         [(V, F, albedo, True), (Vw, Fw, albedo, False)], "bunny 80 mm, 5 mm before a wall")
    raise ExperimentError(f"bias_scene: unknown scene {name!r} (ball-wall, corner, bunny-wall)")


SCENES = ("ball-wall", "corner", "bunny-wall")


def _phase(stack):
    from unwrap.phase_shift import wrapped_phase

    w = wrapped_phase(np.asarray(stack, dtype=np.float64), saturation=None, fill_invalid=False)
    return np.asarray(w.phase), np.asarray(w.B)


def wrap(x):
    return np.angle(np.exp(1j * np.asarray(x)))


def _setup(steps: int):
    system = parity_system(4)
    d_ref = float(np.linalg.norm(system.projector.center_world))
    patterns = phase_sequence(("v",), (1,), steps)
    return system, d_ref, patterns


def cache_dir() -> Path:
    return Path(os.environ.get("SLTWIN_GI_CACHE", Path(tempfile.gettempdir()) / "sltwin_gi_cache"))


def cached_cycles(path: Path | None, render) -> dict:
    """Cycles' images stored at ``path`` (.npz), or ``render()`` (a dict with ``images`` and
    ``seconds_per_frame``) stored there atomically (temporary file, rename); ``path`` None: no
    cache. Returns ``{"images", "seconds_per_frame"}`` (a list of seconds)."""
    if path is not None and path.exists():
        z = np.load(path)
        return {"images": z["images"], "seconds_per_frame": z["seconds_per_frame"].tolist()}
    out = render()
    if path is not None:
        from unwrap.safe_output import atomic_path

        with atomic_path(path) as tmp:     # a unique temporary name: two runs may share a cache folder
            np.savez_compressed(tmp, images=out["images"], seconds_per_frame=np.asarray(out["seconds_per_frame"]))
    return {"images": out["images"], "seconds_per_frame": list(out["seconds_per_frame"])}


def cycles_images(name: str, *, samples: int, bounces: int, seed: int = 0, steps: int = 8, threads: int = 2,
                  cache: bool = True, timeout: float = 1800) -> dict:
    """Cycles' (K, H, W) float64 linear images of scene ``name`` (unit-frequency vertical fringes,
    ``steps`` steps) and its seconds per frame; cached (module docstring)."""
    from synth.blender_twin import render_in_blender

    def render():
        system, d_ref, patterns = _setup(steps)
        proj = np.stack([p.projector_image(system.projector.size, 0.5, 0.5) for p in patterns])
        return render_in_blender(system, bias_scene(name).meshes, proj, exposure=EXPOSURE, reference_distance_mm=d_ref,
                                 threads=threads, samples=samples, bounces=bounces, seed=seed, timeout=timeout)

    key = f"{name}_s{samples}_b{bounces}_seed{seed}_n{steps}.npz"
    return cached_cycles(cache_dir() / key if cache else None, render)


def ours_images(name: str, interreflection: Interreflection | None, *, steps: int = 8, gi=None):
    """Our (K, H, W) float64 linear images of scene ``name`` with the interreflection effect
    (None: direct light only) or the old screen-space term ``gi`` (synth.effects.spec.GlobalIllumination),
    and the render result (its plan and timings)."""
    system, d_ref, patterns = _setup(steps)
    sc = bias_scene(name)
    eff = Effects(exposure=EXPOSURE, fringe_sampling="analytic", reference_distance_mm=d_ref,
                  interreflection=interreflection, global_illumination=gi)
    res = render(Scene(system, sc.objects, patterns, eff), quantised=False)
    return res.images.numpy().astype(np.float64), res


def comparison_mask(geometry, direct_cycles, direct_ours) -> np.ndarray:
    """Pixels where both phases are defined: lit in our direct render, all 4 neighbours on the same
    object (the rim of a faceted Cycles sphere differs from the analytic one), modulation above
    5 % of the median in both direct renders."""
    W, H = geometry.size
    lit = geometry.lit.reshape(H, W).numpy()
    obj = geometry.object_id.reshape(H, W).numpy()
    m = lit.copy()
    same = np.zeros_like(m)
    same[1:-1, 1:-1] = ((obj[1:-1, 1:-1] == obj[:-2, 1:-1]) & (obj[1:-1, 1:-1] == obj[2:, 1:-1])
                        & (obj[1:-1, 1:-1] == obj[1:-1, :-2]) & (obj[1:-1, 1:-1] == obj[1:-1, 2:]))
    m &= same
    _, bc = _phase(direct_cycles)
    _, bo = _phase(direct_ours)
    m &= bc > 0.05 * np.median(bc[m]) if m.any() else m
    m &= bo > 0.05 * np.median(bo[m]) if m.any() else m
    return m


def bias_map(gi_stack, direct_stack) -> np.ndarray:
    """wrap(phi_gi - phi_direct) (H, W) rad at the unit frequency."""
    return wrap(_phase(gi_stack)[0] - _phase(direct_stack)[0])


def compare(reference: np.ndarray, model: np.ndarray, mask: np.ndarray) -> dict:
    """Correlation, RMS of each and RMS of the difference over ``mask`` (rad)."""
    a, b = reference[mask], model[mask]
    corr = float(np.corrcoef(a, b)[0, 1]) if a.std() > 0 and b.std() > 0 else 0.0
    rms_a = float(np.sqrt(np.mean(a ** 2)))
    diff = float(np.sqrt(np.mean((a - b) ** 2)))
    return {"pixels": int(mask.sum()), "correlation": corr, "bias_rms": rms_a,
            "model_rms": float(np.sqrt(np.mean(b ** 2))), "diff_rms": diff,
            "diff_over_bias": diff / rms_a if rms_a > 0 else float("inf"),
            "bias_p99": float(np.percentile(np.abs(a), 99))}


def cycles_bias(name: str, *, samples: int = 256, bounces: int = 4, seeds=(0, 1), steps: int = 8,
                threads: int = 2) -> dict:
    """Cycles' bias map of scene ``name`` averaged over ``seeds`` and its noise: {"bias" (H,W)
    rad, "noise_rms_per_seed" (RMS of the two seeds' difference / sqrt 2 over the comparison
    mask, NaN with one seed), "direct" (Cycles' direct stack), "seconds_per_frame" (GI frames)}."""
    direct = cycles_images(name, samples=1, bounces=0, steps=steps, threads=threads)
    return seeds_bias(direct, [cycles_images(name, samples=samples, bounces=bounces, seed=s, steps=steps,
                                             threads=threads) for s in seeds])


def seeds_bias(direct: dict, outs: list) -> dict:
    """The bias maps of Cycles renders ``outs`` (one per seed, each {"images", "seconds_per_frame"})
    against ``direct``: {"bias" (their circular mean), "maps", "direct" images, "seconds_per_frame"}."""
    maps = [bias_map(o["images"], direct["images"]) for o in outs]
    secs = [t for o in outs for t in o["seconds_per_frame"]]
    mean = wrap(np.angle(np.mean(np.exp(1j * np.stack(maps)), 0)))
    return {"bias": mean, "maps": maps, "direct": direct["images"], "seconds_per_frame": secs}


def save_reference(path, name: str, bias: np.ndarray, mask: np.ndarray, meta: dict) -> None:
    """A small test reference: the bias map as float16 (5e-5 rad resolution at 0.1 rad) and the
    mask, compressed; written atomically."""
    from unwrap.safe_output import atomic_path

    with atomic_path(path) as tmp, open(tmp, "wb") as fh:    # a handle: numpy adds no ".npz" to the name
        np.savez_compressed(fh, bias=np.where(mask, bias, 0).astype(np.float16), mask=np.packbits(mask),
                            shape=np.asarray(mask.shape), **{k: np.asarray(v) for k, v in meta.items()})


def load_reference(path) -> tuple[np.ndarray, np.ndarray, dict]:
    """(bias (H,W) float64, mask (H,W) bool, meta) of :func:`save_reference`."""
    z = np.load(path)
    shape = tuple(int(v) for v in z["shape"])
    mask = np.unpackbits(z["mask"])[: shape[0] * shape[1]].reshape(shape).astype(bool)
    meta = {k: z[k].item() if z[k].ndim == 0 else z[k] for k in z.files if k not in ("bias", "mask", "shape")}
    return z["bias"].astype(np.float64), mask, meta
