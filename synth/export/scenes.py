"""Random scenes for the dataset export: objects, poses, background, materials and effects drawn
from an :class:`~synth.export.config.ExportConfig` with one numpy generator per sample.

Placement: an object's centre is the camera ray of a random pixel in the central 70 % of the image
at a depth ``z0 + depth_mm`` (``z0``: camera depth of the world origin, the calibration board's
centre), kept only where the projector sees it too (the twin's working volume). Meshes get a
uniformly random rotation; surfaces (plane, height field, steps, blobs) face the camera within
their tilt. A background plane (optional) lies ``background_gap_mm`` behind the farthest object
centre, facing the camera within ``background_tilt_deg``.
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from .config import ExportConfig, ExportConfigError, Range
from ..effects.spec import Defocus, Effects, FrameJitter, GlobalIllumination, Interreflection, Noise
from ..errors import SynthError
from ..scenes.meshes import blobs_heights, heightfield_mesh, load_mesh, steps_mesh
from ..scenes.objects import Mesh, Plane, Sphere
from ..scenes.scene import Scene
from ..scenes.sequence import phase_sequence


@lru_cache(maxsize=32)
def cached_mesh(path: str):
    """(vertices centred on the bounding box, faces, largest extent) of a mesh file, read once."""
    V, F = load_mesh(path)
    V = V - (V.min(0) + V.max(0)) / 2
    V.setflags(write=False)
    F.setflags(write=False)
    return V, F, float((V.max(0) - V.min(0)).max())


def check_meshes(cfg: ExportConfig) -> None:
    """Read every configured mesh once (cached), naming a missing or unreadable one."""
    for m in cfg.meshes:
        try:
            cached_mesh(m)
        except SynthError as exc:
            raise ExportConfigError(f"scene.meshes: {exc}") from None


def random_rotation(rng) -> np.ndarray:
    """Uniformly random rotation (unit quaternion from four normal deviates)."""
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def facing_rotation(toward_world: np.ndarray, tilt_deg: float, rng) -> np.ndarray:
    """Object -> world rotation whose +z points along ``toward_world`` tilted by ``tilt_deg`` in a
    random direction, with a random spin about it."""
    z = np.asarray(toward_world, dtype=np.float64)
    z = z / np.linalg.norm(z)
    a = np.array([1.0, 0, 0]) if abs(z[0]) < 0.9 else np.array([0, 1.0, 0])
    x = np.cross(a, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    phi = rng.uniform(0, 2 * math.pi)
    t = math.radians(tilt_deg)
    zt = math.cos(t) * z + math.sin(t) * (math.cos(phi) * x + math.sin(phi) * y)
    xt = np.cross(y if abs(zt @ y) < 0.9 else x, zt)
    xt /= np.linalg.norm(xt)
    spin = rng.uniform(0, 2 * math.pi)
    yt = np.cross(zt, xt)
    xs = math.cos(spin) * xt + math.sin(spin) * yt
    ys = np.cross(zt, xs)
    return np.stack([xs, ys, zt], axis=1)


class TexturedAlbedo:
    """Albedo ``base * (1 + contrast * n(x))`` clipped to [0.02, 1], with ``n`` a sum of random
    plane waves (periods 5-60 mm) in the object frame, normalised to unit amplitude."""

    def __init__(self, base: float, contrast: float, rng, waves: int = 6):
        self.base, self.contrast = float(base), float(contrast)
        d = rng.normal(size=(waves, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        self.k = d * (2 * math.pi / rng.uniform(5.0, 60.0, size=(waves, 1)))
        self.phase = rng.uniform(0, 2 * math.pi, size=waves)

    def __call__(self, local, footprint_mm=None):
        import torch

        k = torch.as_tensor(self.k, dtype=local.dtype)
        n = torch.cos(local @ k.T + torch.as_tensor(self.phase, dtype=local.dtype)).sum(1) / math.sqrt(2 * len(self.phase))
        return (self.base * (1 + self.contrast * n)).clamp(0.02, 1.0)

    def describe(self) -> dict:
        return {"base": self.base, "contrast": self.contrast}


def _draw_position(system, cfg: ExportConfig, rng, tries: int = 50) -> np.ndarray:
    cam, prj = system.camera, system.projector
    z0 = float(cam.t[2])
    for _ in range(tries):
        u = rng.uniform(0.15, 0.85) * cam.width
        v = rng.uniform(0.15, 0.85) * cam.height
        z = z0 + cfg.depth_mm.draw(rng)
        x_cam = np.array([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z])
        X = cam.R.T @ (x_cam - cam.t)
        q = prj.project(X[None])[0]
        if 0.1 * prj.width <= q[0] <= 0.9 * prj.width and 0.1 * prj.height <= q[1] <= 0.9 * prj.height:
            return X
    return X  # the caller's coverage check redraws the whole sample if this one is not seen


def _object(kind: str, name: str, cfg: ExportConfig, system, rng, params: dict):
    """One object of ``kind`` ("mesh" or a procedural kind) at a random pose."""
    size = cfg.size_mm.draw(rng)
    X = _draw_position(system, cfg, rng)
    to_cam = system.camera.center_world - X
    albedo = cfg.albedo.draw(rng)
    p = {"kind": kind, "size_mm": size, "t": X.tolist(), "albedo": albedo}
    if kind == "mesh":
        path = cfg.meshes[int(rng.integers(len(cfg.meshes)))]
        V, F, extent = cached_mesh(path)
        R = random_rotation(rng)
        obj = Mesh(name, R, X, V * (size / extent), F, albedo, True, source=path)
        p["file"] = path.rsplit("/", 1)[-1]
    elif kind == "sphere":
        R = np.eye(3)
        obj = Sphere(name, R, X, albedo, size / 2)
    else:
        R = facing_rotation(to_cam, rng.uniform(0, 45), rng)
        wh = (size, size * rng.uniform(0.6, 1.0))
        if kind == "plane":
            obj = Plane(name, R, X, albedo, wh)
        else:
            if kind == "blobs":
                H = blobs_heights(wh, (96, 96), int(rng.integers(3, 13)), size * rng.uniform(0.08, 0.3),
                                  size * rng.uniform(0.08, 0.25), int(rng.integers(1 << 31)))
                V, F = heightfield_mesh(H, wh)
            elif kind == "heightfield":
                n = int(rng.integers(6, 17))
                coarse = rng.normal(size=(n, n)) * size * rng.uniform(0.02, 0.12)
                import torch
                H = torch.nn.functional.interpolate(torch.tensor(coarse)[None, None], size=(80, 80), mode="bicubic",
                                                    align_corners=True)[0, 0].numpy()
                V, F = heightfield_mesh(H, wh)
            else:  # steps
                bands = int(rng.integers(2, 6))
                V, F = steps_mesh(wh, (rng.uniform(0, 0.3, bands) * size).tolist(), 2)
            obj = Mesh(name, R, X, V, F, albedo, kind != "steps", source=kind)
    p["R"] = R.tolist()
    if rng.uniform() < cfg.texture:
        tex = TexturedAlbedo(albedo, cfg.texture_contrast.draw(rng), rng)
        obj.albedo = tex  # instance attribute: replaces the uniform albedo of this object
        p["texture"] = tex.describe()
    params.setdefault("objects", []).append(p)
    return obj


def _background(objects_t, cfg, system, rng, params):
    cam = system.camera
    axis = cam.R[2]
    depth = max(float(cam.R[2] @ t + cam.t[2]) for t in objects_t) if objects_t else float(cam.t[2])
    d = depth + cfg.background_gap_mm.draw(rng)
    centre_ray = cam.R.T @ np.array([0, 0, 1.0])
    X = cam.center_world + centre_ray * d
    R = facing_rotation(-axis, cfg.background_tilt_deg.draw(rng), rng)
    albedo = cfg.albedo.draw(rng)
    obj = Plane("background", R, X, albedo)
    p = {"kind": "background", "t": X.tolist(), "R": R.tolist(), "albedo": albedo}
    if rng.uniform() < cfg.texture:
        tex = TexturedAlbedo(albedo, cfg.texture_contrast.draw(rng), rng)
        obj.albedo = tex
        p["texture"] = tex.describe()
    params["background"] = p
    return obj


def _draw(r: Range, rng) -> float:
    return r.draw(rng)


def _draw_count(r: Range, rng) -> int:
    """A whole number uniform in [lo, hi]; a fixed one draws nothing (the same scenes as without)."""
    return int(r.lo) if r.lo == r.hi else int(rng.integers(int(r.lo), int(r.hi) + 1))


def draw_effects(cfg: ExportConfig, system, n_objects: int, rng, params: dict) -> Effects:
    """The sample's effects from the config ranges (absent or zero: not simulated)."""
    e = cfg.effects
    kw = {"A": cfg.A, "B": cfg.B, "bits": e.get("bits", 8), "shadows": e.get("shadows", "auto")}
    for k in ("exposure", "ambient", "vignetting", "projector_gamma", "gain"):
        if k in e:
            kw[k] = _draw(e[k], rng)
    if "noise" in e and not e["noise"]["full_well_e"].off:
        kw["noise"] = Noise(_draw(e["noise"]["full_well_e"], rng),
                            _draw(e["noise"].get("read_noise_e", Range(0.0, 0.0)), rng), int(rng.integers(1 << 62)))
    for k, dev in (("projector_defocus", system.projector), ("camera_defocus", system.camera)):
        if k in e and not e[k]["aperture_mm"].off:
            aperture = _draw(e[k]["aperture_mm"], rng)
            focus = float(dev.t[2]) + _draw(e[k].get("focus_offset_mm", Range(0.0, 0.0)), rng)
            n = _draw_count(e[k]["samples"], rng) if "samples" in e[k] else 0  # thin lens (defocus_model)
            if aperture > 0:
                kw[k] = Defocus(aperture, max(focus, 1.0), 4, n)
    if "global_illumination" in e:
        g = e["global_illumination"]
        sub, mm = g.get("subsurface", Range(0.0, 0.0)), g.get("scatter_mm", Range(2.0, 2.0))
        per = tuple((_draw(sub, rng), _draw(mm, rng)) for _ in range(n_objects))
        inter = _draw(g.get("interreflection", Range(0.0, 0.0)), rng)
        gi = GlobalIllumination(per_object=per, interreflection=inter,
                                interreflection_mm=_draw(g.get("interreflection_mm", Range(40.0, 40.0)), rng))
        if gi.active:
            kw["global_illumination"] = gi
    if "interreflection" in e and not e["interreflection"]["chance"].off:
        ir = e["interreflection"]
        if rng.uniform() < _draw(ir["chance"], rng):
            b = ir.get("bounces", Range(1.0, 1.0))
            kw["interreflection"] = Interreflection(
                bounces=int(rng.integers(int(b.lo), int(b.hi) + 1)),
                patch_px=_draw(ir.get("patch_px", Range(32.0, 32.0)), rng))
    if "frame_jitter" in e:  # drawn last: configs without it draw the same scenes as before
        fj = FrameJitter(_draw(e["frame_jitter"].get("offset", Range(0.0, 0.0)), rng),
                         _draw(e["frame_jitter"].get("gain", Range(0.0, 0.0)), rng), int(rng.integers(1 << 62)))
        if fj.active:
            kw["frame_jitter"] = fj
    eff = Effects(**kw)
    params["effects"] = eff.to_dict()
    return eff


def draw_scene(cfg: ExportConfig, system, rng) -> tuple[Scene, dict]:
    """One random scene (objects, background, effects) and its drawn parameters (JSON-able)."""
    params: dict = {}
    n = int(rng.integers(cfg.objects[0], cfg.objects[1] + 1))
    objects = []
    for i in range(n):
        use_mesh = cfg.meshes and rng.uniform() < cfg.mesh_fraction
        kind = "mesh" if use_mesh else cfg.procedural[int(rng.integers(len(cfg.procedural)))]
        objects.append(_object(kind, f"object{i}", cfg, system, rng, params))
    layout = "free" if cfg.layouts == ("free",) else cfg.layouts[int(rng.integers(len(cfg.layouts)))]
    if layout != "free":
        from .layouts import LAYOUTS
        objects += LAYOUTS[layout](objects, params, system, cfg, rng, facing_rotation)
    elif rng.uniform() < cfg.background:
        objects.append(_background([o.t.numpy() for o in objects], cfg, system, rng, params))
    eff = draw_effects(cfg, system, len(objects), rng, params)
    patterns = phase_sequence(cfg.orientations, cfg.frequencies, list(cfg.steps))
    if eff.frame_jitter is not None:
        from ..effects.frame_jitter import frame_factors
        o, g = frame_factors(eff.frame_jitter, len(patterns))
        params["frame_jitter"] = {"offsets": o.tolist(), "gains": g.tolist()}  # per frame, pattern order
    return Scene(system, objects, patterns, eff, "export-sample"), params
