"""Render a scene: geometry once, then the whole pattern stack, then the camera stages.

SYNOPSIS

    >>> from synth import render, Scene, Plane, phase_sequence
    >>> from calib import default_system
    >>> import numpy as np
    >>> scene = Scene(default_system(), [Plane("wall", np.eye(3), [0, 0, 0])],
    ...               phase_sequence(("v",), (8,), 4))
    >>> result = render(scene)
    >>> tuple(result.images.shape), result.images.dtype
    ((4, 480, 640), torch.uint8)

Only the stages a scene asks for are built, and a stage that cannot change this scene's image is
skipped; ``result.plan`` lists every stage with "run" or the reason it was skipped (also logged
to the ``synth`` logger at DEBUG, :mod:`synth.renderer.plan_log`).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import SynthError
from .geometry import Geometry, compute_geometry
from ..effects.global_illumination import apply_global_illumination
from .plan_log import PlanLog
from .projection import linear_model, nonlinear_values

F64 = torch.float64
from ..effects.sensor import add_noise, camera_defocus, quantise
from ..scenes.sequence import check_fringe_periods
from .truth import fringe_frequencies, phase_truth

@dataclass
class RenderResult:
    """Images and ground truth of one render.

    - images: (K,H,W) counts in [0, 2^bits-1] (uint8 for 8 bits, else int32) (or float32 linear values when
      ``quantised`` is False).
    - linear: (K,H,W) float32 linear camera values before noise and quantisation (kept only
      when asked for).
    - names: K pattern names; geometry: the per-pixel buffers; plan: stage decisions;
      timings: seconds per stage.
    """

    images: torch.Tensor
    names: list
    geometry: Geometry
    plan: list
    timings: dict
    bits: int
    linear: torch.Tensor | None = None

    def truth(self, projector_size, patterns) -> dict:
        """{orientation: {frequency: (phase, order, valid)}} for the stack's fringes."""
        return {o: {f: phase_truth(self.geometry, projector_size, o, f) for f in fs}
                for o, fs in fringe_frequencies(patterns).items()}


_CHUNK = 1 << 14  # lit pixels per chunk of the fused pattern + quantisation stage (72 x 16k float32 = 4.7 MB)


def _quantised_stack(geometry, lit, idx, C, rows, other, p_other, K, eff) -> torch.Tensor:
    """(K, N) quantised counts: unlit pixels hold their quantised ambient term; lit pixels the
    patterns, computed and quantised chunk by chunk."""
    N = geometry.lit.numel()
    ambient = geometry.ambient_term.to(torch.float32)
    base = quantise(ambient.clone(), eff.bits, eff.gain, eff.saturation)
    out = base.expand(K, N).clone()
    scale_lit = geometry.radiance_scale[lit]
    amb_lit = ambient[lit]
    for j in range(0, lit.numel(), _CHUNK):
        sl = slice(j, j + _CHUNK)
        vals = torch.empty((K, min(_CHUNK, lit.numel() - j)), dtype=torch.float32)
        if idx:
            chunk = torch.mm(C[:, 1:], rows[:, sl]).add_(amb_lit[sl])  # row 0 of C is the ambient's 1
            if len(idx) == K:
                vals = chunk
            else:
                vals[idx] = chunk
        if other:
            vals[other] = (scale_lit[sl] * p_other[:, sl]).to(torch.float32) + amb_lit[sl]
        q = quantise(vals, eff.bits, eff.gain, eff.saturation)
        first, last = int(lit[j]), int(lit[min(j + _CHUNK, lit.numel()) - 1])
        if last - first + 1 == q.shape[1]:  # a run of consecutive pixels (lit is sorted): plain copy
            out[:, first:last + 1] = q
        else:
            out.index_copy_(1, lit[sl], q)
    return out


def _optics_plan(eff, geometry, lit, plan):
    """Which optical stages this render runs (their skips go to the plan): returns the projector
    blur sigmas at the lit pixels (None: no blur), whether the camera blurs and whether global
    illumination is applied."""
    if not eff.projector_defocus:
        plan.info("projector defocus: skipped (not asked for)")
    elif lit.numel() == 0 or float(geometry.sigma_prj[lit].max()) < 1e-3:
        plan.info("projector defocus: skipped (no lit pixel is out of focus)")
    if eff.projector_gamma == 1.0:
        plan.info("projector gamma: skipped (1.0)")
    sig = geometry.sigma_prj[lit] if (geometry.sigma_prj is not None and lit.numel()) else None
    if sig is not None and float(sig.max()) < 1e-3:
        sig = None
    if eff.camera_defocus is None:
        plan.info("camera defocus: skipped (not asked for)")
        cam_blur = False
    elif geometry.sigma_cam is None or float(geometry.sigma_cam.max()) < 1e-3:
        plan.info("camera defocus: skipped (every pixel in focus)")
        cam_blur = False
    else:
        cam_blur = True
    gi = eff.global_illumination
    gi_on = gi is not None and gi.active and lit.numel() > 0
    if gi is None:
        plan.info("global illumination: skipped (not asked for)")
    elif not gi_on:
        plan.info("global illumination: skipped (%s)", "zero fractions" if not gi.active else "nothing lit")
    return sig, cam_blur, gi_on


def _interreflection_plan(scene, lit, plan) -> bool:
    """Whether this render runs synth.effects.interreflection (its skip goes to the plan)."""
    from ..effects.interreflection import skip_reason

    if scene.effects.interreflection is None:
        plan.info("interreflection: skipped (not asked for)")
        return False
    why = "nothing lit" if lit.numel() == 0 else skip_reason(scene.objects)
    if why:
        plan.info("interreflection: skipped (%s)", why)
        return False
    return True


def _linear_images(geometry, lit, idx, C, rows, other, p_other, K, eff, cam_blur, timings, t, *,
                   gi=None, f_px=None, plan=None, scene=None):
    """The (K, H, W) float32 images before the sensor: basis rows over the whole image (ambient
    where unlit), global illumination (``gi``; ``f_px`` the camera focal length, px) and camera
    defocus on the rows, then the pattern combinations; ``scene``: given when
    synth.effects.interreflection runs (first, on the rows). ``t``: when the pattern stage started
    (its time goes to ``timings``)."""
    W, H = geometry.size
    N = W * H
    full = torch.zeros((rows.shape[0] + 1, N), dtype=torch.float32)
    full[0] = geometry.ambient_term
    full[1:, lit] = rows
    images = torch.empty((K, N), dtype=torch.float32)
    nl = None
    if other:
        nl = geometry.ambient_term.to(torch.float32).repeat(len(other), 1)
        nl[:, lit] += (geometry.radiance_scale[lit] * p_other).to(torch.float32)
    timings["patterns"] = time.perf_counter() - t
    if scene is not None:
        from ..effects.interreflection import apply_interreflection

        t = time.perf_counter()
        full, nl, _ = apply_interreflection(full, nl, scene, geometry, other, log=plan)
        timings["interreflection"] = time.perf_counter() - t
    if gi is not None:
        # linear too: applied to the basis rows (and the other patterns' images)
        t = time.perf_counter()
        full = apply_global_illumination(full, geometry, gi, f_px, log=plan)
        if nl is not None:
            nl = apply_global_illumination(nl, geometry, gi, f_px)
        timings["global illumination"] = time.perf_counter() - t
    if cam_blur:
        # blur is linear and its per-pixel level weights too: blurring the R basis rows and
        # combining them equals blurring the K images (R ~ K / 5 for fringe stacks)
        t = time.perf_counter()
        sigma = geometry.sigma_cam.reshape(H, W)
        lv = eff.camera_defocus.levels
        full = camera_defocus(full.reshape(-1, H, W), sigma, lv).reshape(-1, N)
        if nl is not None:
            nl = camera_defocus(nl.reshape(-1, H, W), sigma, lv).reshape(-1, N)
        timings["camera defocus"] = time.perf_counter() - t
    t = time.perf_counter()
    if idx == list(range(K)):
        torch.mm(C, full, out=images)
    elif idx:
        images[idx] = C @ full
    if nl is not None:
        images[other] = nl
    timings["patterns"] += time.perf_counter() - t
    return images.reshape(K, H, W)


def _frame_jitter(images, eff, timings):
    """synth.effects.frame_jitter on the linear stack (before the sensor; kept in ``linear``)."""
    fj = eff.frame_jitter
    if fj is None or not fj.active:
        return images
    from ..effects.frame_jitter import apply_frame_jitter

    t = time.perf_counter()
    images = apply_frame_jitter(images, fj)
    timings["frame jitter"] = time.perf_counter() - t
    return images


def _sensor(images, eff, quantised: bool, timings):
    """The PSF's tail, sensor noise, then gain, saturation, the response curve and quantisation
    (or all but the quantisation); synth.effects.response."""
    t = time.perf_counter()
    if eff.camera_psf_tail is not None and eff.camera_psf_tail.fraction > 0:
        from ..effects.response import psf_tail

        images = psf_tail(images, eff.camera_psf_tail.fraction, eff.camera_psf_tail.sigma_px)
        timings["camera PSF tail"] = time.perf_counter() - t
        t = time.perf_counter()
    if eff.noise is not None:
        gen = torch.Generator().manual_seed(int(eff.noise.seed))
        images = add_noise(images, eff.noise, gen)
        timings["noise"] = time.perf_counter() - t
    t = time.perf_counter()
    if eff.camera_gamma != 1.0:
        from ..effects.response import camera_response

        images = camera_response(images, eff.camera_gamma, eff.gain, eff.saturation)
        if quantised:
            images = quantise(images, eff.bits, 1.0, eff.saturation ** eff.camera_gamma)
            timings["gain + response + quantisation"] = time.perf_counter() - t
    elif quantised:
        images = quantise(images, eff.bits, eff.gain, eff.saturation)
        timings["gain + quantisation"] = time.perf_counter() - t
    elif eff.gain != 1.0 or eff.saturation != 1.0:
        images = (images * eff.gain).clamp(0, eff.saturation)
    return images


def check_render_memory(n_images: int, camera_size, available: int | None = None) -> int:
    """Refuse (:class:`SynthError`) a render whose image stack cannot fit in memory: ``n_images``
    float32 images of ``camera_size`` (W, H), about twice over (the stack and its noisy or
    quantised copy), against 80 % of the available memory (``MemAvailable``); e.g.
    ``--steps 100000`` asks for 600001 images. Returns the estimate in bytes."""
    from unwrap.learned.memory import available_bytes

    W, H = (int(v) for v in camera_size)
    need = 2 * 4 * int(n_images) * W * H
    available = available_bytes() if available is None else int(available)
    if need > 0.8 * available:
        raise SynthError(f"patterns: {n_images} images of {W}x{H} px need about {need / 1e9:.3g} GB, this machine "
                         f"has {available / 1e9:.3g} GB available; render fewer steps or frequencies")
    return need


def _sensor_plan(eff, plan) -> bool:
    """Plan lines of the sensor-side stages; True when the PSF tail or the response curve runs."""
    if eff.noise is None:
        plan.info("sensor noise: skipped (not asked for)")
    tail = eff.camera_psf_tail
    plan.info("camera PSF tail: %s", "run" if tail is not None and tail.fraction > 0
              else "skipped (not asked for)" if tail is None else "skipped (fraction 0)")
    if eff.camera_gamma == 1.0:
        plan.info("camera response: skipped (gamma 1.0)")
    fj = eff.frame_jitter
    plan.info("frame jitter: %s", "run" if fj is not None and fj.active
              else "skipped (not asked for)" if fj is None else "skipped (zero offset and gain)")
    return (eff.camera_gamma != 1.0 or (tail is not None and tail.fraction > 0)
            or (eff.frame_jitter is not None and eff.frame_jitter.active))


def _thin_lens(scene, keep_linear, quantised, plan) -> RenderResult:
    """synth.effects.thin_lens: the aperture average of pinhole renders, then the sensor once."""
    from ..effects.thin_lens import aperture_average, without_sampling

    t0 = time.perf_counter()
    avg = aperture_average(scene, render, log=plan)
    if avg is None:  # every pixel in focus: the plain render, bit for bit
        return render(without_sampling(scene), keep_linear=keep_linear, quantised=quantised, log=plan)
    images, geometry, timings = avg
    _sensor_plan(scene.effects, plan)
    images = _frame_jitter(images, scene.effects, timings)
    linear = images.clone() if keep_linear else None
    images = _sensor(images, scene.effects, quantised, timings)
    timings["total"] = time.perf_counter() - t0
    return RenderResult(images, [p.name for p in scene.patterns], geometry, plan.lines, timings, scene.effects.bits,
                        linear)


def render(scene, *, keep_linear: bool = False, quantised: bool = True, geometry: Geometry | None = None,
           log=None) -> RenderResult:
    """Render every pattern of ``scene``. ``geometry`` reuses a previous geometry stage of the
    same scene pose (e.g. to render another pattern sequence; not with ``*_defocus.samples``,
    whose aperture points each need their own). ``log``: a ``logging.Logger`` the
    plan lines also go to, at DEBUG (default: the ``synth`` logger)."""
    check_fringe_periods(scene.patterns, scene.system.projector.size)
    check_render_memory(len(scene.patterns), scene.system.camera.size)
    plan = PlanLog.of(log)
    eff = scene.effects
    if any(d is not None and d.samples for d in (eff.camera_defocus, eff.projector_defocus)):
        if geometry is not None:
            raise SynthError("render(geometry=...) cannot be reused with camera_defocus / projector_defocus "
                             "samples: every aperture point needs its own geometry")
        return _thin_lens(scene, keep_linear, quantised, plan)
    timings: dict = {}
    t0 = time.perf_counter()
    if geometry is None:
        geometry = compute_geometry(scene, log=plan)
        timings.update({f"geometry: {k}": v for k, v in geometry.timings.items()})
    else:
        plan.info("geometry: reused")
    W, H = geometry.size
    K = len(scene.patterns)
    lit = torch.nonzero(geometry.lit).squeeze(1)

    t = time.perf_counter()
    sig, cam_blur, gi_on = _optics_plan(eff, geometry, lit, plan)
    ir_on = _interreflection_plan(scene, lit, plan)
    u, v = geometry.u_p[lit], geometry.v_p[lit]
    psize = scene.system.projector.size
    # images = ambient + scale * p. Linear patterns: one matrix product (K, R) @ (R, N) over basis
    # rows [ambient, scale, scale*a*cos Phi, scale*a*sin Phi, ...] built in float64 and cast to
    # float32 (see synth.effects.sensor); no per-pattern temporaries.
    idx, coef, basis = linear_model(scene.patterns, u, v, psize, eff, sig)
    C = torch.cat([torch.ones((len(idx), 1), dtype=F64), coef], 1).to(torch.float32)
    rows = (geometry.radiance_scale[lit] * basis).to(torch.float32)  # (R, M) at lit pixels
    other = [k for k in range(K) if k not in set(idx)]
    p_other = nonlinear_values(scene.patterns, other, u, v, psize, eff, sig, log=plan) if other else None
    if lit.numel() == 0:
        plan.info("patterns: no camera pixel is lit by the projector (empty image apart from ambient light)")
    cam_after = _sensor_plan(eff, plan)
    fused = (quantised and not cam_blur and not gi_on and not ir_on and eff.noise is None and not keep_linear
             and not cam_after)
    if fused:
        # nothing between the patterns and the quantiser acts across pixels: compute the lit
        # pixels in cache-sized chunks and quantise them at once; unlit pixels hold ambient only
        images = _quantised_stack(geometry, lit, idx, C, rows, other, p_other, K, eff)
        timings["patterns"] = time.perf_counter() - t
        plan.info("gain + quantisation: fused with the pattern stage (no camera defocus or noise in between)")
        images = images.reshape(K, H, W)
        linear = None
    else:
        images = _linear_images(geometry, lit, idx, C, rows, other, p_other, K, eff, cam_blur, timings, t,
                                gi=eff.global_illumination if gi_on else None,
                                f_px=max(scene.system.camera.fx, scene.system.camera.fy), plan=plan,
                                scene=scene if ir_on else None)
        images = _frame_jitter(images, eff, timings)
        linear = images.clone() if keep_linear else None
        images = _sensor(images, eff, quantised, timings)
    timings["total"] = time.perf_counter() - t0
    return RenderResult(images, [p.name for p in scene.patterns], geometry, plan.lines, timings, eff.bits, linear)
