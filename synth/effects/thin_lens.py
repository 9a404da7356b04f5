"""Camera and projector defocus as thin lenses: the average of pinhole renders from points of
the apertures.

A thin lens focused at camera depth ``F`` (mm) sends every ray that leaves the aperture point
``a = (a_x, a_y, 0)`` (camera frame, mm, on a disc of diameter ``aperture_mm``) towards the
pixel's point on the focus plane ``F (x, y, 1)`` (``(x, y)`` the pixel's undistorted normalised
coordinates). The rays of one aperture point share an origin, so they form a pinhole camera at
``a`` with the same orientation, whose normalised coordinates are sheared: ``x' = x - a_x / F``,
``y' = y - a_y / F`` (points on the focus plane map to the same pixel from every aperture
point). A pixel's value is the mean, over the aperture, of what each of these pinholes sees:
occlusion is exact (a wall point hidden from the lens centre behind an object's outline is seen
from part of the aperture and mixes in, and an object's blurred outline covers the wall only
as far as the lens sees it), as in Cycles' depth of field, and unlike a blur of the finished
image, which mixes what the centre sees across the edge.

``samples`` aperture points on a Vogel spiral (golden-angle, equal areas; an even number as
mirrored pairs; 1 point: the lens centre, i.e. the pinhole). With few points a far surface shows ``samples`` shifted copies. (A
per-sample prefilter, blurring each pinhole image by the Gaussian of one sample's share of the
disc, sigma ``c / (4 sqrt(samples))``, was measured (plain spiral) against 128 samples on the ball-wall scene
and did not help: 8 samples 0.62 / 0.58 of the bias RMS with / without, 16 samples 0.21 / 0.21;
it is not offered.)

Everything after the camera rays (projector coordinates, shadows, shading) runs per aperture
point through the normal renderer; the interreflection too with ``interreflection.thin_lens =
"exact"``, while the default ``"shared"`` computes it once at the lens centre and looks it up at
each aperture point's surface points, exactly only where the centre does not see them
(synth.effects.lens_indirect; validated in docs/synth.md); noise, gain and quantisation run once on the
average (and the PSF tail and response curve, synth.effects.response). The ground truth is the lens centre's pinhole geometry.
"""
from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np
import torch

from ..scenes.objects import Rays

F64 = torch.float64
GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))


#: plan lines of an aperture point's render that the average replaces (render() adds the sensor's)
SAMPLE_PLAN_REPLACED = ("camera defocus: skipped", "projector defocus: skipped", "sensor noise", "camera PSF tail",
                        "camera response", "gain + quantisation", "interreflection: shared", "frame jitter")


def aperture_points(n: int) -> np.ndarray:
    """(n, 2) points of the unit disc, equal areas: a Vogel spiral (radius sqrt((i + 1/2) / m),
    angle i times the golden angle, i < m) of m = n / 2 points and their mirror images through
    the centre when n is even (every odd moment exactly 0: no net parallax shift of what is out of
    focus; a plain 32-point spiral's mean is 1.6 % of the radius off the centre), the plain
    spiral of n points when n is odd; n = 1 gives the centre."""
    if n < 1:
        raise ValueError(f"aperture_points: n must be >= 1, got {n}")
    if n == 1:
        return np.zeros((1, 2))
    m = n // 2 if n % 2 == 0 else n
    i = np.arange(m, dtype=np.float64)
    r = np.sqrt((i + 0.5) / m)
    a = i * GOLDEN_ANGLE
    p = np.stack([r * np.cos(a), r * np.sin(a)], 1)
    return np.concatenate([p, -p]) if n % 2 == 0 else p


def aperture_rays(camera, use_distortion: bool, offset_mm, focus_mm: float) -> tuple[Rays, torch.Tensor]:
    """The camera's pixel rays leaving the aperture point ``offset_mm`` (a_x, a_y) (camera frame,
    mm) towards each pixel's point on the focus plane (camera depth ``focus_mm``): (Rays, valid
    (N,) bool). Offset (0, 0) returns the pinhole rays of synth.renderer.geometry.camera_rays."""
    from ..renderer.geometry import camera_rays

    rays, ok = camera_rays(camera, use_distortion)
    ax, ay = (float(v) for v in offset_mm)
    if ax == 0.0 and ay == 0.0:
        return rays, ok
    a = torch.tensor([ax, ay, 0.0], dtype=F64)
    R, t = rays.R_dev_world, rays.t_dev_world
    xy = rays.xy - a[:2] / float(focus_mm)
    d = xy @ R[:2] + R[2]  # R^T (x', y', 1)
    d = d / torch.linalg.norm(d, dim=1, keepdim=True)
    origin = rays.origin + a @ R  # C + R^T a
    return Rays(origin, d, xy, R, t - a, rays.cell, "camera"), ok


def projector_at(projector, offset_mm, focus_mm: float):
    """The projector as an inverse camera seen from its aperture point ``offset_mm`` (b_x, b_y)
    (projector frame, mm), lens focused at projector depth ``focus_mm``: light from DMD pixel q
    leaves through b towards q's point on the focus plane, so a point X (projector frame) gets
    the pixel at normalised ``(X - b)_xy / X_z + b / F``: a pinhole at b whose principal point
    moves by ``K (b / F)``. Exact without lens distortion; with distortion, the distortion is
    evaluated at the pinhole-at-b coordinates instead of the sheared ones (an error of about
    the distortion's gradient times ``|b| / F``, e.g. 1e-3 x 2.5e-3 in normalised units)."""
    bx, by = (float(v) for v in offset_mm)
    K = np.array(projector.K, dtype=np.float64)
    K[0, 2] += (K[0, 0] * bx + K[0, 1] * by) / focus_mm
    K[1, 2] += K[1, 1] * by / focus_mm
    return projector.with_(K=K, t=np.asarray(projector.t, dtype=np.float64) - np.array([bx, by, 0.0]))


def _active(dof, sigma) -> bool:
    return dof is not None and dof.samples > 0 and sigma is not None and float(sigma.max()) >= 1e-3


def without_sampling(scene):
    """``scene`` with both defocus ``samples`` set to 0 (the Gaussian-blur route)."""
    eff = scene.effects
    cdof, pdof = eff.camera_defocus, eff.projector_defocus
    return replace(scene, effects=replace(eff, camera_defocus=None if cdof is None else replace(cdof, samples=0),
                                          projector_defocus=None if pdof is None else replace(pdof, samples=0)))


def aperture_average(scene, render_fn, log=None):
    """The mean (K, H, W) float32 linear stack over the aperture points of ``scene`` (whose
    ``camera_defocus.samples`` or ``projector_defocus.samples`` is >= 1; module docstring), before
    the sensor: ``(images, geometry of the lens centre, timings)``; None when no device needs
    sampling (its blur sigma below 1e-3 px at every pixel, the Gaussian route's own test): then
    :func:`without_sampling` renders the scene, bit for bit as without any defocus sampling
    (the plan says "skipped (every pixel in focus)"). ``render_fn``: synth.renderer.render.render.

    Both devices sampled: aperture point i of the camera goes with point n - 1 - i of the
    projector (inner with outer): each device's own average is exact, their joint integral is
    approximated by this pairing."""
    from ..renderer.geometry import camera_rays, compute_geometry, nearest_surface
    from ..renderer.plan_log import PlanLog

    plan = PlanLog.of(log)
    eff = scene.effects
    cdof, pdof = eff.camera_defocus, eff.projector_defocus
    plain = without_sampling(scene)
    cam, prj = scene.system.camera, scene.system.projector
    cam_dist = eff.camera_distortion and bool(np.any(cam.distortion))
    # the lens centre's (pinhole) rays and their hits: computed once, for the centre's geometry
    # and for every aperture point of a projector-only lens (the camera does not move)
    t0 = time.perf_counter()
    pinhole = camera_rays(cam, cam_dist)
    pinhole_hits = nearest_surface(scene.objects, pinhole[0])
    timings = {"thin lens: ray hits": time.perf_counter() - t0}
    centre = compute_geometry(plain, rays=pinhole, hits=pinhole_hits, log=PlanLog.of(None))
    lit = centre.lit
    cam_on = _active(cdof, None if centre.sigma_cam is None else centre.sigma_cam[centre.hit])
    prj_on = _active(pdof, None if centre.sigma_prj is None else centre.sigma_prj[lit])
    if not cam_on and not prj_on:
        return None
    n = max(cdof.samples if cam_on else 0, pdof.samples if prj_on else 0)
    unit = aperture_points(n)
    if cam_on:
        plan.info("camera defocus: thin lens, %d aperture sample(s), blur disc up to %.3g px", n,
                  4 * float(centre.sigma_cam[centre.hit].max()))
    if prj_on:
        plan.info("projector defocus: thin lens, %d aperture sample(s), blur disc up to %.3g px", n,
                  4 * float(centre.sigma_prj[lit].max()))
    d_ref = eff.reference_distance_mm or float(np.linalg.norm(prj.center_world))
    sample_eff = replace(plain.effects, camera_defocus=None if cam_on else plain.effects.camera_defocus,
                         projector_defocus=None if prj_on else plain.effects.projector_defocus,
                         noise=None, gain=1.0, saturation=1.0, camera_gamma=1.0, camera_psf_tail=None,
                         frame_jitter=None, reference_distance_mm=d_ref)   # camera stages: once, on the average
    shared = _shared_indirect(plain, centre, timings)
    acc = None
    for i in range(n):
        sub = PlanLog.of(None)
        s_scene = replace(scene, effects=sample_eff)
        if prj_on:
            b = unit[n - 1 - i if cam_on else i] * (pdof.aperture_mm / 2.0)
            s_scene = replace(s_scene, system=replace(scene.system, projector=projector_at(prj, b, pdof.focus_mm)))
        if cam_on:
            g = compute_geometry(s_scene, rays=aperture_rays(cam, cam_dist, unit[i] * (cdof.aperture_mm / 2.0),
                                                             cdof.focus_mm), log=sub)
        else:
            g = compute_geometry(s_scene, rays=pinhole, hits=pinhole_hits, log=sub)
        if shared is not None:
            g.shared_indirect = shared  # read by synth.effects.interreflection.apply_interreflection
        res = render_fn(s_scene, keep_linear=False, quantised=False, geometry=g, log=sub)
        if i == 0:  # the first point's stage decisions, less those the average makes itself
            for line in sub.lines:
                if not line.startswith(SAMPLE_PLAN_REPLACED):
                    plan.info(line)
        acc = res.images.to(F64) if acc is None else acc.add_(res.images.to(F64))
        for k, v in list(g.timings.items()) + list(res.timings.items()):
            key = f"thin lens: {k}"
            timings[key] = timings.get(key, 0.0) + v
    if shared is not None:
        plan.info("interreflection: %s", shared.describe())
    return acc.div_(n).to(torch.float32), centre, timings


def _shared_indirect(plain, centre, timings):
    """synth.effects.lens_indirect.SharedIndirect of the lens centre when the scene's
    interreflection runs and asks for ``thin_lens = "shared"`` (else None: every aperture point
    computes its own)."""
    from .interreflection import skip_reason
    from .lens_indirect import SharedIndirect

    ir = plain.effects.interreflection
    if ir is None or ir.thin_lens != "shared" or skip_reason(plain.objects) or not bool(centre.lit.any()):
        return None
    t0 = time.perf_counter()
    shared = SharedIndirect(plain, centre)
    timings["thin lens: shared indirect (centre)"] = time.perf_counter() - t0
    return shared
