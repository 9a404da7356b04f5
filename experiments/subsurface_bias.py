"""The unit-frequency phase bias that subsurface scattering adds, Cycles' random walk against our
screen-space subsurface term (synth.effects.global_illumination, a per-object material:
``global_illumination.per_object``).

Scene ``ball-wall`` of :mod:`experiments.gi_bias` (ball 4.6 mm before a wall, albedo 0.8), both
objects a plaster-like material: Cycles' Principled BSDF with subsurface weight ``WEIGHT`` and
radius ``RADIUS_MM`` (random walk), 4 diffuse bounces, 256 samples, two seeds. The bias of
subsurface scattering is ``wrap(phi_sss+gi - phi_gi)``: Cycles against its own 4-bounce frames
without subsurface (experiments.gi_bias.cycles_images), ours (interreflection on both sides,
the subsurface term added on one) against ours without it. Our scatter sigma for Cycles' radius
is the one fitted on a slab's 48-period contrast in experiments.gi_reference (0.78 mm for
weight 0.8, radius 4 mm; docs/dataset.md), used unchanged.
"""
from __future__ import annotations


import numpy as np

from .gi_bias import EXPOSURE, _setup, bias_scene, cache_dir, cached_cycles

WEIGHT = 0.8
RADIUS_MM = 4.0
#: our Gaussian scatter sigma (mm) for Cycles' radius 4 mm at weight 0.8 (experiments.gi_reference)
SIGMA_MM = 0.78


def cycles_sss_images(name: str = "ball-wall", *, samples: int = 256, seed: int = 0, steps: int = 8,
                      threads: int = 2, timeout: float = 7200) -> dict:
    """Cycles' (K, H, W) linear images of ``name`` with random-walk subsurface scattering on every
    object and 4 bounces; cached like experiments.gi_bias.cycles_images."""
    from synth.blender_twin import render_in_blender

    def render():
        system, d_ref, patterns = _setup(steps)
        proj = np.stack([p.projector_image(system.projector.size, 0.5, 0.5) for p in patterns])
        return render_in_blender(system, bias_scene(name).meshes, proj, exposure=EXPOSURE, reference_distance_mm=d_ref,
                                 threads=threads, samples=samples, bounces=4, seed=seed, timeout=timeout,
                                 subsurface={"weight": WEIGHT, "radius_mm": RADIUS_MM, "method": "RANDOM_WALK"})

    return cached_cycles(cache_dir() / f"{name}_sss_w{WEIGHT:g}_r{RADIUS_MM:g}_s{samples}_b4_seed{seed}_n{steps}.npz",
                         render)


def cycles_sss_bias(name: str = "ball-wall", *, samples: int = 256, seeds=(0, 1), steps: int = 8) -> dict:
    """Cycles' subsurface bias (circular mean over ``seeds``) against its 4-bounce frames without
    subsurface of the same seed, its per-seed maps, its direct (1-sample) stack and the seconds
    per subsurface frame."""
    from .gi_bias import bias_map, cycles_images, wrap

    maps, secs = [], []
    for s in seeds:
        gi = cycles_images(name, samples=samples, bounces=4, seed=s, steps=steps)
        sss = cycles_sss_images(name, samples=samples, seed=s, steps=steps)
        maps.append(bias_map(sss["images"], gi["images"]))
        secs += list(sss["seconds_per_frame"])
    mean = wrap(np.angle(np.mean(np.exp(1j * np.stack(maps)), 0)))
    direct = cycles_images(name, samples=1, bounces=0, steps=steps)["images"]
    return {"bias": mean, "maps": maps, "direct": direct, "seconds_per_frame": secs}


def ours_sss_bias(name: str = "ball-wall", *, fraction: float = WEIGHT, sigma_mm: float = SIGMA_MM,
                  steps: int = 8) -> dict:
    """Our subsurface bias (interreflection on both sides), our direct stack, its geometry and the
    render time (s) of the subsurface stack."""
    from synth.effects.spec import GlobalIllumination, Interreflection

    from .gi_bias import bias_map, ours_images

    direct, r0 = ours_images(name, None, steps=steps)
    gi, _ = ours_images(name, Interreflection(), steps=steps)
    sss, r = ours_images(name, Interreflection(), steps=steps,
                         gi=GlobalIllumination(subsurface=fraction, scatter_mm=sigma_mm))
    return {"bias": bias_map(sss, gi), "direct": direct, "geometry": r0.geometry, "seconds": r.timings["total"]}
