"""The geometry stage: camera rays, nearest hits, projector coordinates, shading, cast shadows.

Computed once per scene pose and reused by every pattern of the stack. All float64: projector
coordinates feed absolute phase at up to ~100 periods (2*pi*96 rad), where float32's 7 digits
would cost ~1e-4 rad.

Frames: world (mm); camera frame ``x_c = R_c X + t_c``; projector frame likewise. Per-pixel
buffers are flattened over the camera image, index ``row * W + col``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from calib.distortion import distort, undistort

from ..scenes.objects import Rays
from .plan_log import PlanLog

F64 = torch.float64


@dataclass
class Geometry:
    """Per-pixel buffers, each (N,) or (N,3) with N = H*W (camera image, row-major)."""

    size: tuple                 # camera (W, H)
    hit: torch.Tensor           # bool: a surface is seen
    object_id: torch.Tensor     # int64, -1 where no hit
    depth: torch.Tensor         # z in the camera frame (mm), NaN where no hit
    points_cam: torch.Tensor    # (N,3) mm, NaN where no hit
    normals_cam: torch.Tensor   # (N,3) unit, facing the camera, NaN where no hit
    u_p: torch.Tensor           # projector column (px), NaN where not projectable
    v_p: torch.Tensor           # projector row (px)
    z_prj: torch.Tensor         # depth in the projector frame (mm)
    in_field: torch.Tensor      # bool: inside the projector's image (and its lens model)
    facing: torch.Tensor        # bool: the surface faces the projector (cos_p > 0)
    shadow: torch.Tensor        # bool: another surface blocks the projector
    lit: torch.Tensor           # hit & in_field & facing & ~shadow
    albedo: torch.Tensor        # (N,) albedo (0 where no hit)
    radiance_scale: torch.Tensor  # exposure*albedo*cos_p*falloff*vignetting, 0 where not lit
    ambient_term: torch.Tensor    # exposure*ambient*albedo*vignetting
    sigma_prj: torch.Tensor | None = None   # (N,2) projector blur sigma (px) along u_p, v_p
    sigma_cam: torch.Tensor | None = None   # (N,) camera blur sigma (px)
    timings: dict = field(default_factory=dict)


def _pixel_grid(size) -> np.ndarray:
    W, H = size
    v, u = np.meshgrid(np.arange(H, dtype=np.float64), np.arange(W, dtype=np.float64), indexing="ij")
    return np.stack([u.ravel(), v.ravel()], axis=1)


_RAY_CACHE: dict = {}
_RAY_CACHE_SIZE = 4


def camera_rays(camera, use_distortion: bool) -> tuple[Rays, torch.Tensor]:
    """One ray per camera pixel centre: (Rays, valid (N,) bool). Distortion is inverted by
    Newton (calib.distortion.undistort); without distortion only K is inverted.

    The rays depend only on the camera (size, K, distortion, pose), not on the scene, so the
    last few are kept (a session of board poses, or many scenes, seen by one camera pays the
    Newton inversion once). The returned tensors are shared: never modify them in place."""
    key = (tuple(camera.size), camera.K.tobytes(), np.asarray(camera.distortion, dtype=np.float64).tobytes(),
           camera.R.tobytes(), camera.t.tobytes(), bool(use_distortion))
    if key in _RAY_CACHE:
        return _RAY_CACHE[key]
    q = _pixel_grid(camera.size)
    xyd = camera.pixels_to_normalized(q)
    if use_distortion and camera.distortion.size and np.any(camera.distortion):
        xy, ok = undistort(xyd, camera.distortion)
    else:
        xy, ok = xyd, np.ones(len(q), dtype=bool)
    xy = torch.from_numpy(np.ascontiguousarray(xy))
    ok = torch.from_numpy(np.ascontiguousarray(ok))
    R = torch.tensor(camera.R)
    t = torch.tensor(camera.t)
    d = xy @ R[:2] + R[2]  # R^T (x, y, 1)
    d /= torch.linalg.norm(d, dim=1, keepdim=True)
    if not bool(ok.all()):
        xy = torch.where(ok[:, None], xy, torch.full_like(xy, float("nan")))
    out = (Rays(torch.tensor(camera.center_world), d, xy, R, t, 1.0 / max(camera.fx, camera.fy), "camera"), ok)
    if len(_RAY_CACHE) >= _RAY_CACHE_SIZE:
        _RAY_CACHE.pop(next(iter(_RAY_CACHE)))
    _RAY_CACHE[key] = out
    return out


def _scatter(values: torch.Tensor, index: torch.Tensor, N: int, fill) -> torch.Tensor:
    """Full (N, ...) buffer holding ``values`` at ``index`` and ``fill`` elsewhere."""
    out = torch.full((N, *values.shape[1:]), fill, dtype=values.dtype)
    out[index] = values
    return out


def nearest_surface(objects, rays: Rays):
    """Nearest hit among objects: (t (N,), object index (N,), normal world (N,3), local (N,3))."""
    N = rays.dirs.shape[0]
    t_best = torch.full((N,), float("inf"), dtype=F64)
    idx = torch.full((N,), -1, dtype=torch.int64)
    normal = torch.zeros((N, 3), dtype=F64)
    local = torch.zeros((N, 3), dtype=F64)
    for i, obj in enumerate(objects):
        h = obj.intersect(rays)
        closer = h.t < t_best
        t_best = torch.where(closer, h.t, t_best)
        idx = torch.where(closer, torch.full_like(idx, i), idx)
        normal = torch.where(closer[:, None], h.normal, normal)
        local = torch.where(closer[:, None], h.local, local)
    return t_best, idx, normal, local


def projector_field_box(projector, use_distortion: bool) -> np.ndarray:
    """(xmin, xmax, ymin, ymax) of the projector's field in undistorted normalised coordinates,
    5 % enlarged. A point outside cannot be in the image even if a (folding) lens polynomial maps
    it there."""
    W, H = projector.size
    s = np.linspace(0, 1, 101)
    border = np.concatenate([np.stack([s * W - 0.5, np.full_like(s, -0.5)], 1),
                             np.stack([s * W - 0.5, np.full_like(s, H - 0.5)], 1),
                             np.stack([np.full_like(s, -0.5), s * H - 0.5], 1),
                             np.stack([np.full_like(s, W - 0.5), s * H - 0.5], 1)])
    xyd = projector.pixels_to_normalized(border)
    if use_distortion and projector.distortion.size and np.any(projector.distortion):
        xy, ok = undistort(xyd, projector.distortion)
        xy = xy[ok]
    else:
        xy = xyd
    lo, hi = xy.min(0), xy.max(0)
    pad = 0.05 * (hi - lo)
    return np.array([lo[0] - pad[0], hi[0] + pad[0], lo[1] - pad[1], hi[1] + pad[1]])


def project_to_projector(projector, points_world: torch.Tensor, use_distortion: bool):
    """World points (N,3) -> (u_p, v_p, z_prj, xy_undistorted (N,2), in_field (N,))."""
    R = torch.tensor(projector.R)
    t = torch.tensor(projector.t)
    p = points_world @ R.T + t
    z = p[:, 2]
    front = z > 1e-9
    zs = torch.where(front, z, torch.ones_like(z))
    xy = p[:, :2] / zs[:, None]
    coeffs = projector.distortion if use_distortion else np.zeros(0)
    xyd = distort(xy, coeffs)
    u = projector.fx * xyd[:, 0] + projector.skew * xyd[:, 1] + projector.cx
    v = projector.fy * xyd[:, 1] + projector.cy
    W, H = projector.size
    box = projector_field_box(projector, use_distortion)
    in_field = (front & (u >= -0.5) & (u <= W - 0.5) & (v >= -0.5) & (v <= H - 0.5)
                & (xy[:, 0] >= box[0]) & (xy[:, 0] <= box[1]) & (xy[:, 1] >= box[2]) & (xy[:, 1] <= box[3]))
    return u, v, z, xy, in_field


def defocus_sigma(defocus, f_px: float, z: torch.Tensor) -> torch.Tensor:
    """Gaussian sigma (px) of the thin-lens blur disc at depth z (mm): ``c / 4``, the per-axis
    standard deviation of a uniform disc of diameter ``c = aperture * f_px * |1/z - 1/focus|``."""
    c = defocus.aperture_mm * f_px * (1.0 / z.clamp(min=1e-6) - 1.0 / defocus.focus_mm).abs()
    return c / 4.0


def needs_shadow_pass(objects) -> tuple[bool, str]:
    if not objects:
        return False, "empty scene"
    if len(objects) == 1 and objects[0].convex:
        return False, f"a single convex {objects[0].kind} cannot cast a shadow on itself"
    return True, f"{len(objects)} object(s), {sum(not o.convex for o in objects)} non-convex"


class _Clock:
    def __init__(self, timings):
        self.timings = timings

    def __call__(self, name):
        import time
        clock = self

        class _C:
            def __enter__(self):
                self.t0 = time.perf_counter()

            def __exit__(self, *a):
                clock.timings[name] = clock.timings.get(name, 0.0) + time.perf_counter() - self.t0
        return _C()


def _cast_shadows(scene, shadows, C_p, dir_p, dist_p, xy_prj, candidates, log) -> torch.Tensor:
    """(M,) bool: surface points (of the M hit pixels) whose path to the projector centre ``C_p``
    another surface blocks; only ``candidates`` (in the projector's field, facing it) are traced.
    ``shadows`` None follows ``effects.shadows`` and skips the pass when no object can shadow."""
    prj = scene.system.projector
    want = {"on": True, "off": False}.get(scene.effects.shadows) if shadows is None else shadows
    needed, why = needs_shadow_pass(scene.objects)
    shadow = torch.zeros(candidates.numel(), dtype=torch.bool)
    if want is False:
        log.info("cast shadows: skipped (turned off)")
        return shadow
    if not needed and want is None:
        log.info("cast shadows: skipped (%s)", why)
        return shadow
    cand = torch.nonzero(candidates).squeeze(1)
    if cand.numel():
        prays = Rays(C_p, -dir_p[cand], xy_prj[cand], torch.tensor(prj.R), torch.tensor(prj.t),
                     1.0 / max(prj.fx, prj.fy), "projector")
        t_block = torch.full((cand.numel(),), float("inf"), dtype=F64)
        for o in scene.objects:  # distances only: no normals or object-frame points
            t_block = torch.minimum(t_block, o.distance(prays))
        d = dist_p[cand]
        shadow[cand] = t_block < d * (1 - 1e-6)
    log.info("cast shadows: computed (%s): %d shadowed pixel(s)", why, int(shadow.sum()))
    return shadow


def _shading(scene, obj, local, t, cos_c, cos_p, dist_p, ray_xy, lit):
    """Albedo, radiance scale (exposure x albedo x Lambert x falloff x vignetting, 0 where not lit)
    and ambient term of the M hit pixels, each (M,) float64. ``cos_c``: |cos| between the camera
    ray and the normal (sets the pixel's footprint on the surface, for the albedo's anti-aliasing);
    ``ray_xy``: the normalised camera coordinates of the rays (vignetting)."""
    eff, cam, prj = scene.effects, scene.system.camera, scene.system.projector
    albedo = torch.zeros(t.numel(), dtype=F64)
    footprint = t / max(cam.fx, cam.fy) / torch.sqrt(cos_c.clamp(min=0.05))
    for i, o in enumerate(scene.objects):
        m = obj == i
        if bool(m.any()):
            albedo[m] = o.albedo(local[m], footprint[m])
    shade = cos_p.clamp(min=0) if eff.shading == "lambert" else torch.ones_like(cos_p)
    if eff.falloff:
        d_ref = eff.reference_distance_mm or float(np.linalg.norm(prj.center_world))
        shade = shade * (d_ref / dist_p.clamp(min=1e-9)) ** 2
    vign = torch.ones(t.numel(), dtype=F64)
    if eff.vignetting > 0:
        rx = torch.nan_to_num(ray_xy, nan=0.0)
        cos4 = 1.0 / (1.0 + (rx ** 2).sum(1)) ** 2
        vign = 1.0 - eff.vignetting * (1.0 - cos4)
    radiance_scale = torch.where(lit, eff.exposure * albedo * shade * vign, torch.zeros_like(albedo))
    ambient_term = eff.exposure * eff.ambient * albedo * vign
    return albedo, radiance_scale, ambient_term


def _defocus_sigmas(scene, in_field, z_prj, depth, hi, N):
    """Per-pixel Gaussian blur sigmas (N, 2) of the projector (px) and (N,) of the camera (px),
    each None when its defocus is off; ``hi`` maps the M hit pixels into the N image pixels."""
    eff, cam, prj = scene.effects, scene.system.camera, scene.system.projector
    sigma_prj = sigma_cam = None
    if eff.projector_defocus is not None:
        z = torch.where(in_field, z_prj, torch.full_like(z_prj, eff.projector_defocus.focus_mm))
        sigma_prj = _scatter(torch.stack([defocus_sigma(eff.projector_defocus, prj.fx, z),
                                          defocus_sigma(eff.projector_defocus, prj.fy, z)], 1), hi, N, 0.0)
    if eff.camera_defocus is not None:
        sigma_cam = _scatter(defocus_sigma(eff.camera_defocus, max(cam.fx, cam.fy), depth), hi, N, 0.0)
    return sigma_prj, sigma_cam


def compute_geometry(scene, *, shadows: bool | None = None, log=None, rays=None, hits=None) -> Geometry:
    """Run the geometry stage of ``scene`` (see the module docstring). ``shadows`` overrides
    the scene's choice (None: follow ``effects.shadows``). ``log``: where the stage decisions go
    (:class:`synth.renderer.plan_log.PlanLog`, or a ``logging.Logger`` they go to at DEBUG).
    ``rays``: (Rays, valid) replacing the camera's pinhole rays (one aperture point of
    synth.effects.thin_lens); the buffers stay in the camera frame. ``hits``: the
    :func:`nearest_surface` of these rays (or of the pinhole rays) among ``scene.objects``, when
    the caller already has it (the projector-only thin lens: one camera, many projectors)."""
    log = PlanLog.of(log)
    sysm, eff = scene.system, scene.effects
    cam, prj = sysm.camera, sysm.projector
    timings: dict = {}
    clock = _Clock(timings)
    W, H = cam.size
    N = W * H
    cam_dist = eff.camera_distortion and bool(np.any(cam.distortion))
    prj_dist = eff.projector_distortion and bool(np.any(prj.distortion))
    with clock("camera rays"):
        rays, ray_ok = camera_rays(cam, cam_dist) if rays is None else rays
    if not cam_dist:
        log.info("camera distortion: skipped (%s)", "zero coefficients" if eff.camera_distortion else "turned off")
    if hits is None:
        with clock("ray hits"):
            hits = nearest_surface(scene.objects, rays)
    t_all, obj_all, n_all, local_all = hits
    hit = torch.isfinite(t_all) & ray_ok
    # from here on only the M pixels that see a surface are computed, then scattered into (N,)
    # buffers at the end (a ball fills ~5 % of the image)
    hi = torch.nonzero(hit).squeeze(1)
    t, obj, n_world, local = t_all[hi], obj_all[hi], n_all[hi], local_all[hi]
    dirs = rays.dirs[hi]
    nan = float("nan")
    X = rays.origin + t[:, None] * dirs
    # normals face the camera (two-sided surfaces)
    flip = (n_world * dirs).sum(1) > 0
    n_world = torch.where(flip[:, None], -n_world, n_world)
    Rc = torch.tensor(cam.R)
    points_cam = X @ Rc.T + torch.tensor(cam.t)
    normals_cam = n_world @ Rc.T
    depth = points_cam[:, 2]

    with clock("projector coordinates"):
        u_p, v_p, z_prj, xy_prj, in_field = project_to_projector(prj, X, prj_dist)
    if not prj_dist:
        log.info("projector distortion: skipped (%s)", "zero coefficients" if eff.projector_distortion else "turned off")
    C_p = torch.tensor(prj.center_world)
    to_p = C_p - X
    dist_p = torch.linalg.norm(to_p, dim=1)
    dir_p = to_p / dist_p.clamp(min=1e-12)[:, None]
    cos_p = (n_world * dir_p).sum(1)
    facing = cos_p > 0

    with clock("shadows"):
        shadow = _cast_shadows(scene, shadows, C_p, dir_p, dist_p, xy_prj, in_field & facing, log)
    lit = in_field & facing & ~shadow

    with clock("shading"):
        albedo, radiance_scale, ambient_term = _shading(scene, obj, local, t, (n_world * dirs).sum(1).abs(),
                                                        cos_p, dist_p, rays.xy[hi], lit)
    if eff.vignetting == 0:
        log.info("vignetting: skipped (strength 0)")
    if eff.ambient == 0:
        log.info("ambient light: skipped (0)")
    sigma_prj, sigma_cam = _defocus_sigmas(scene, in_field, z_prj, depth, hi, N)
    proj_ok = z_prj > 0
    u_p = torch.where(proj_ok, u_p, torch.full_like(u_p, nan))
    v_p = torch.where(proj_ok, v_p, torch.full_like(v_p, nan))
    return Geometry((W, H), hit, _scatter(obj, hi, N, -1), _scatter(depth, hi, N, nan),
                    _scatter(points_cam, hi, N, nan), _scatter(normals_cam, hi, N, nan),
                    _scatter(u_p, hi, N, nan), _scatter(v_p, hi, N, nan), _scatter(z_prj, hi, N, nan),
                    _scatter(in_field, hi, N, False), _scatter(facing, hi, N, False),
                    _scatter(shadow, hi, N, False), _scatter(lit, hi, N, False), _scatter(albedo, hi, N, 0.0),
                    _scatter(radiance_scale, hi, N, 0.0), _scatter(ambient_term, hi, N, 0.0),
                    sigma_prj, sigma_cam, timings)
