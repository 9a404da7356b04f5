"""Scene layouts like real captures for the dataset export (issue 21, item 2): objects a few mm to
cm in front of a wall, or standing on a table (optionally with a wall behind it: a concave
corner), lit and seen at the twin's working distance, so that the effects real scenes make -
cast shadows beside outlines, light bouncing between object and background, grazing surfaces -
appear in the training data.

Frames: world mm (the calibration board's frame: z towards the camera), camera frame as in
calib (x right, y down, z along the optical axis). Every drawn number goes into the sample's
``params["layout"]`` (JSON), so a sample can be rebuilt and explained from its file alone.

Layouts (``scene.layouts`` lists those to draw from, one uniformly per sample; "free" is the
original layout of :mod:`synth.export.scenes`):

- ``wall``: an unbounded wall facing the camera within ``wall_tilt_deg`` (a large tilt gives
  grazing light), its centre on the optical axis ``wall_depth_mm`` behind the farthest object
  centre (camera depth); each object is pushed along its camera ray until its nearest point is
  ``wall_gap_mm`` in front of the wall.
- ``table``: a bounded table top (800 x 800 mm) whose normal is the camera's "up" (-y) tilted
  towards the camera by ``table_elevation_deg`` (the camera looks down on it at that angle; a
  small angle is grazing), through a point of the lower image half at ``depth_mm``; each object
  is lifted along the table normal until its lowest point touches the top (contact shadows).
  With chance ``table_wall`` an unbounded wall stands on the table, ``wall_depth_mm`` (camera
  depth) behind the farthest object centre, upright and facing the camera (a room's corner).
"""
from __future__ import annotations

import math

import numpy as np
import torch

from ..scenes.objects import Mesh, Plane, Sphere

TABLE_MM = 800.0   # side of the table top


def _cam_to_world(system, x_cam):
    cam = system.camera
    return cam.R.T @ (np.asarray(x_cam, dtype=np.float64) - cam.t)


def _dir_to_world(system, d_cam):
    return system.camera.R.T @ np.asarray(d_cam, dtype=np.float64)


def _ray(system, u, v):
    """Unit world direction of the camera ray through pixel (u, v): the camera model's own
    (:meth:`calib.device.DeviceModel.rays_world`: skew and distortion included), so a point placed
    along it projects back to (u, v)."""
    _, d, _ = system.camera.rays_world(np.array([u, v], dtype=np.float64))
    return d


def support_offsets(obj) -> np.ndarray:
    """(K, 3) world offsets from the object's centre that bound it along any direction (mesh
    vertices, bounded plane corners); a sphere is handled by :func:`extent_along`."""
    R = obj.R.numpy()
    if isinstance(obj, Mesh):
        return obj.V.numpy() @ R.T
    if isinstance(obj, Plane) and obj.size_mm is not None:
        w, h = obj.size_mm
        c = np.array([[-w, -h, 0], [w, -h, 0], [w, h, 0], [-w, h, 0]]) / 2
        return c @ R.T
    return np.zeros((1, 3))


def extent_along(obj, n) -> float:
    """min over the object's points of n . (point - centre) (mm; <= 0)."""
    if isinstance(obj, Sphere):
        return -obj.radius
    return float((support_offsets(obj) @ n).min())


def _move(obj, p: dict, X) -> None:
    obj.t = torch.tensor(np.asarray(X, dtype=np.float64))
    p["t"] = [float(v) for v in X]


def _wall(system, cfg, rng, depth: float, facing_rotation, name: str = "wall"):
    """An unbounded wall through the camera-axis point at ``depth`` (camera z, mm), facing the
    camera within ``wall_tilt_deg``: (Plane, its unit normal (world, towards the camera), a
    point on it, params)."""
    cam = system.camera
    P = _cam_to_world(system, [0.0, 0.0, depth])
    tilt = cfg.wall_tilt_deg.draw(rng)
    R = facing_rotation(-cam.R[2], tilt, rng)
    albedo = cfg.wall_albedo.draw(rng)
    obj = Plane(name, R, P, albedo)
    return obj, R[:, 2].copy(), P, {"kind": name, "t": P.tolist(), "R": R.tolist(), "albedo": albedo,
                                    "tilt_deg": tilt, "depth_mm": depth}


def place_before_wall(objects, params, system, cfg, rng, facing_rotation) -> list:
    """Layout ``wall``: the wall and every object pushed along its camera ray to ``wall_gap_mm``
    before it. Returns the extra objects (the wall); fills ``params['layout']``."""
    cam = system.camera
    z0 = float(cam.t[2])
    obj_depths = [float(cam.R[2] @ o.t.numpy() + cam.t[2]) for o in objects]
    wall_depth = max(obj_depths) + cfg.wall_depth_mm.draw(rng)
    wall, n, P, wp = _wall(system, cfg, rng, wall_depth, facing_rotation)
    gaps = []
    C = cam.center_world
    for obj, p in zip(objects, params["objects"]):
        gap = cfg.wall_gap_mm.draw(rng)
        d = obj.t.numpy() - C
        d = d / np.linalg.norm(d)
        dn = float(d @ n)
        if dn > -1e-3:  # a ray that never reaches the wall (grazing): leave the object where it is
            gaps.append(None)
            continue
        # move along the ray by s: n . (X + s d - P) + min_k n . offset_k = gap
        X = obj.t.numpy()
        s = (gap - float(n @ (X - P)) - extent_along(obj, n)) / dn
        _move(obj, p, X + s * d)
        gaps.append(gap)
    params["layout"] = {"kind": "wall", "z0": z0, "wall": wp, "gaps_mm": gaps}
    return [wall]


def table_foot(system, u, v, n, A) -> np.ndarray:
    """(3,) world point where the camera ray through pixel (u, v) meets the table plane (normal
    ``n``, through ``A``); ``A`` where the ray runs (nearly) parallel to it or away from it."""
    C = system.camera.center_world
    d = _ray(system, u, v)
    dn = float(d @ n)
    return C + d * (float(n @ (A - C)) / dn) if dn < -1e-3 else np.asarray(A, dtype=np.float64)


def place_on_table(objects, params, system, cfg, rng, facing_rotation) -> list:
    """Layout ``table``: a table top (and with chance ``table_wall`` a wall behind it); every
    object re-placed on the top at a random visible point. Returns the extra objects."""
    cam = system.camera
    z0 = float(cam.t[2])
    elev = math.radians(cfg.table_elevation_deg.draw(rng))
    n_cam = np.array([0.0, -math.cos(elev), -math.sin(elev)])     # up, tilted towards the camera
    v_anchor = rng.uniform(0.55, 0.8) * cam.height
    depth = z0 + cfg.depth_mm.draw(rng)
    A = _cam_to_world(system, [0.0, (v_anchor - cam.cy) / cam.fy * depth, depth])
    n = _dir_to_world(system, n_cam)
    # table frame: z = n, x along the camera's x projected on the table
    x = _dir_to_world(system, [1.0, 0, 0])
    x = x - (x @ n) * n
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(n, x), n], axis=1)
    albedo = cfg.wall_albedo.draw(rng)
    table = Plane("table", R, A, albedo, (TABLE_MM, TABLE_MM))
    layout = {"kind": "table", "z0": z0, "elevation_deg": math.degrees(elev), "v_anchor_px": v_anchor,
              "table": {"t": A.tolist(), "R": R.tolist(), "albedo": albedo, "size_mm": [TABLE_MM, TABLE_MM]}}
    for obj, p in zip(objects, params["objects"]):
        u = rng.uniform(0.2, 0.8) * cam.width
        v = rng.uniform(0.35, 0.9) * cam.height
        _move(obj, p, table_foot(system, u, v, n, A) - extent_along(obj, n) * n)
    extra = [table]
    if rng.uniform() < cfg.table_wall:
        far = max(float(cam.R[2] @ o.t.numpy() + cam.t[2]) for o in objects) + cfg.wall_depth_mm.draw(rng)
        back = -cam.R[2] - (-cam.R[2] @ n) * n          # horizontal direction towards the camera
        back /= np.linalg.norm(back)
        Rw = facing_rotation(back, 0.0, rng)
        Pw = _cam_to_world(system, [0.0, 0.0, far])
        Pw = Pw + n * float(n @ (A - Pw))                 # the wall's centre on the table plane
        # the depth is drawn from object centres: move the wall back until no object reaches it
        nearest = min(float(back @ (o.t.numpy() - Pw)) + extent_along(o, back) for o in objects)
        Pw = Pw - back * max(0.0, TABLE_WALL_CLEARANCE_MM - nearest)
        wall = Plane("wall", Rw, Pw, cfg.wall_albedo.draw(rng))
        layout["wall"] = {"t": Pw.tolist(), "R": Rw.tolist(), "albedo": wall.albedo_value, "depth_mm": far,
                          "clearance_mm": max(nearest, TABLE_WALL_CLEARANCE_MM)}
        extra.append(wall)
    params["layout"] = layout
    return extra


#: least gap (mm) between the table's wall and the nearest object point (the wall of ``place_on_table``)
TABLE_WALL_CLEARANCE_MM = 2.0

#: layout name -> f(objects, params, system, cfg, rng, facing_rotation) -> extra objects (the caller,
#: synth.export.scenes, passes its facing_rotation: no import back into it)
LAYOUTS = {"wall": place_before_wall, "table": place_on_table}
