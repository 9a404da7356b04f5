"""One sample of the dataset export: draw a scene from (seed, index), render it, and reduce the
images to what every unwrapping method needs (unwrap.dataset_schema).

Stages (timed): ``geometry`` (scene draw + rays, hits, shadows), ``patterns`` (pattern stack,
global illumination, camera defocus; with defocus ``samples``, the thin lens's aperture renders,
each with its own geometry, where synth.export.defocus_model keeps it), ``noise`` (noise +
quantisation), ``phase`` (N-step wrapped phase and modulation of every frequency), ``labels``
(true coordinate and orders, masks, the label check).

Label check (the paper's way of making labels, supplementary section 3): traditional MF from the
unit frequency on the noise-free render must give the geometric order. It runs twice per
orientation and frequency: on a *clean* render (same geometry, direct light only: no defocus,
global illumination, interreflection, gamma, frame jitter or noise, float32 linear images) - this validates the labels, and is
0 up to float32 ties - and on the noise-free render *with* the sample's effects, where defocus
and global illumination bias the unit phase: those mismatches are the errors the effects alone
cause, counted apart in the interior and within 1 px of an edge. Sample ``index`` depends only on ``(seed, index)``: its generator is
``numpy.random.default_rng([seed, index, attempt])``, and ``attempt`` counts the redraws of a
scene whose objects cover too little of the image.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from unwrap.dataset_schema import (FLAG_LOW_MODULATION, FLAG_OUT_OF_RANGE, FLAG_SATURATED, MASK_EDGE, MASK_LIT,
                                   MASK_SHADOW, MASK_SURFACE, encode_modulation, encode_phase)
from unwrap.phase_shift import wrapped_phase
from unwrap.temporal import mf_unwrap

from .config import ExportConfig
from .defocus_model import choose_defocus_model, sampled
from .scenes import draw_scene
from ..errors import SynthError
from ..renderer.geometry import compute_geometry
from ..renderer.plan_log import PlanLog
from ..renderer.render import render
from ..renderer.truth import phase_truth


@dataclass
class Sample:
    """Arrays of one sample, named as in the file (without the sample axis)."""

    index: int
    arrays: dict
    params: dict
    label_check: np.ndarray        # (O, F, 4) int32: mismatches (clean interior, clean edge, effects
                                   # interior, effects edge), -1 not checked
    timings: dict = field(default_factory=dict)


def edge_mask(geometry, depth_jump_mm: float = 3.0) -> np.ndarray:
    """(H, W) bool: pixels within 1 px of a change of object, of lit state or of a depth jump."""
    W, H = geometry.size
    obj = geometry.object_id.reshape(H, W).numpy()
    lit = geometry.lit.reshape(H, W).numpy()
    z = np.nan_to_num(geometry.depth.reshape(H, W).numpy(), nan=-1e9)
    e = np.zeros((H, W), dtype=bool)
    for a, b in (((slice(None), slice(1, None)), (slice(None), slice(None, -1))),
                 ((slice(1, None), slice(None)), (slice(None, -1), slice(None)))):
        d = (obj[a] != obj[b]) | (lit[a] != lit[b]) | (np.abs(z[a] - z[b]) > depth_jump_mm)
        e[a] |= d
        e[b] |= d
    return e


def draw_covered(cfg: ExportConfig, system, index: int, timings: dict, sampler=None):
    """Sample ``index``'s (scene, lens-centre Geometry, params, rng), redrawn until the objects cover
    ``export.min_object_fraction`` of the image (what :func:`make_sample` renders; benchmarks that
    render the export's scenes another way draw them here too)."""
    W, H = system.camera.size
    for attempt in range(cfg.max_redraws):
        rng = np.random.default_rng([cfg.seed, index, attempt])
        t = time.perf_counter()
        sys_i = sampler(rng) if sampler is not None else system
        scene, params = draw_scene(cfg, sys_i, rng)
        if sampler is not None:
            from calib.io.calibration_json import system_to_dict
            params["system"] = system_to_dict(sys_i)
        plan = PlanLog()
        geom = compute_geometry(scene, log=plan)
        timings["geometry"] = timings.get("geometry", 0.0) + time.perf_counter() - t
        n_obj = len(params.get("objects", []))
        covered = float(((geom.object_id < n_obj) & (geom.object_id >= 0) & geom.lit).sum()) / (W * H)
        if covered >= cfg.min_object_fraction:
            params.update(attempt=attempt, object_fraction=covered, plan=plan.lines)
            return scene, geom, params, rng
    raise SynthError(f"sample {index}: the objects covered less than export.min_object_fraction = "
                     f"{cfg.min_object_fraction} of the image in {cfg.max_redraws} draws; check scene.size_mm, "
                     "scene.depth_mm and the system")


def make_sample(cfg: ExportConfig, system, index: int, sampler=None) -> Sample:
    """Render and reduce sample ``index`` (see the module docstring). ``sampler``: optional
    :class:`synth.export.posterior.PosteriorSampler` drawing the sample's system."""
    timings: dict = {}
    scene, geom, params, rng = draw_covered(cfg, system, index, timings, sampler)
    scene = choose_defocus_model(cfg, scene, geom, params)
    system = scene.system
    W, H = system.camera.size
    t = time.perf_counter()
    plan = PlanLog()
    # the thin lens renders every aperture point's own geometry (its lens centre's is geom's)
    res = render(scene, geometry=None if sampled(scene) else geom, keep_linear=True, log=plan)
    params["plan"] = params["plan"] + plan.lines
    total_render = time.perf_counter() - t
    noise_t = res.timings.get("noise", 0.0) + res.timings.get("gain + quantisation", 0.0)
    timings["noise"] = noise_t
    timings["patterns"] = total_render - noise_t
    # --- phase: N-step least squares of the noisy, quantised images ---------------------------
    t = time.perf_counter()
    top = float((1 << res.bits) - 1)
    names = {n: k for k, n in enumerate(res.names)}
    imgs = res.images.numpy()
    O, F = len(cfg.orientations), len(cfg.frequencies)
    arrays: dict = {}
    lit = geom.lit.reshape(H, W).numpy()
    for o in cfg.orientations:
        ph = np.zeros((F, H, W), np.int16)
        mod = np.zeros((F, H, W), np.uint16)
        flags = np.zeros((F, H, W), np.uint8)
        for j, (f, n) in enumerate(zip(cfg.frequencies, cfg.steps)):
            stack = imgs[[names[p.name] for p in scene.patterns
                          if p.orientation == o and p.frequency == f]]
            w = wrapped_phase(stack, min_modulation=cfg.min_modulation * top, saturation=top)
            ph[j] = encode_phase(np.where(w.valid, w.phase, 0.0))
            mod[j] = encode_modulation(w.B / top)
            flags[j] = (w.low_modulation * FLAG_LOW_MODULATION | w.saturated * FLAG_SATURATED
                        | w.out_of_range * FLAG_OUT_OF_RANGE).astype(np.uint8)
        arrays[f"{o}/phase"], arrays[f"{o}/modulation"], arrays[f"{o}/flags"] = ph, mod, flags
    timings["phase"] = time.perf_counter() - t
    # --- labels: geometric truth, masks, label check on the noise-free render -------------------
    t = time.perf_counter()
    edge = edge_mask(geom)
    masks = (geom.hit.reshape(H, W).numpy() * MASK_SURFACE | lit * MASK_LIT
             | geom.shadow.reshape(H, W).numpy() * MASK_SHADOW | edge * MASK_EDGE).astype(np.uint8)
    arrays["masks"] = masks
    Wp, Hp = system.projector.size
    check = np.full((O, F, 4), -1, np.int32)
    linear = res.linear.numpy()
    clean_scene = replace(scene, effects=replace(scene.effects, projector_defocus=None, camera_defocus=None,
                                                 global_illumination=None, interreflection=None,
                                                 projector_gamma=1.0, noise=None, frame_jitter=None))
    clean_imgs = render(clean_scene, geometry=replace(geom, sigma_prj=None, sigma_cam=None), quantised=False,
                        log=PlanLog()).images.numpy()
    for i, o in enumerate(cfg.orientations):
        coord = (geom.u_p if o == "v" else geom.v_p).reshape(H, W).numpy()
        arrays[f"{o}/coordinate"] = np.where(lit, coord, np.nan).astype(np.float32)
        orders = np.full((F, H, W), -1, np.int8)
        phases = {"clean": {}, "effects": {}}
        for j, f in enumerate(cfg.frequencies):
            _, order, _ = phase_truth(geom, (Wp, Hp), o, f)
            orders[j] = order
            ks = [names[p.name] for p in scene.patterns if p.orientation == o and p.frequency == f]
            for name, stack in (("clean", clean_imgs[ks]), ("effects", linear[ks])):
                phases[name][f] = np.asarray(wrapped_phase(stack.astype(np.float64), saturation=None).phase)
        arrays[f"{o}/order"] = orders
        if cfg.frequencies[0] <= 1.0:
            width = Wp if o == "v" else Hp
            for j, f in enumerate(cfg.frequencies[1:], start=1):
                for c, name in ((0, "clean"), (2, "effects")):
                    ph = phases[name]
                    r = mf_unwrap([ph[cfg.frequencies[0]], ph[f]], (cfg.frequencies[0], f), width=width, valid=lit)
                    wrong = lit & (np.asarray(r.order) != orders[j])
                    check[i, j, c:c + 2] = [int((wrong & ~edge).sum()), int((wrong & edge).sum())]
    timings["labels"] = time.perf_counter() - t
    params["index"] = index
    return Sample(index, arrays, params, check, timings)


def params_json(sample: Sample) -> str:
    return json.dumps(sample.params, separators=(",", ":"), default=_json_default)


def _json_default(v):
    if isinstance(v, (np.generic,)):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, torch.Tensor):
        return v.tolist()
    if isinstance(v, tuple):
        return list(v)
    return str(v)
