"""The unit-frequency phase bias that camera defocus makes across occlusion edges, Cycles against
the twin (issue 21 item 1: "a camera pixel integrates what its PSF sees, not a blur of the
finished image").

Scene ``ball-wall-dof``: the 25.4 mm ball of :mod:`experiments.gi_bias` at the world origin, a
matte wall (600 x 600 mm) at z = -60 mm (34.6 mm behind the ball), albedo 0.8, on the parity twin
(ideal system, 160x120 camera, f = 648 px), 8 steps of vertical fringes at f = 1; the camera
focused on the ball's front (camera depth ``FOCUS_MM``), a circular aperture of ``APERTURE_MM``
diameter: the wall (depth ~907 mm) blurs into a disc of ~6 px, the ball's outline (~848 mm) ~2 px.
(At 160x120 a pixel is 4 of the 640x480 camera's, so the same discs there take a 4x smaller
aperture per pixel of blur: this is a strongly defocused but not an exotic setting.)

Each renderer is compared with itself, as in :mod:`experiments.gi_bias`: bias =
``wrap(phi_defocused - phi_pinhole)``. Cycles: thin-lens depth of field (the driver's
``camera_dof``), direct light only, ``samples`` samples and two seeds (reference = circular mean,
noise = RMS of the difference / sqrt 2), against its 1-sample pinhole frames. Ours: the aperture
average (:mod:`synth.effects.thin_lens`, ``camera_defocus.samples``) and, for the record, the
old blur of the finished image (``camera_defocus`` without ``samples``).

Mask: lit in our pinhole render, 4-neighbours on the same object, modulation above 5 % of the
median in both pinhole renders (:func:`experiments.gi_bias.comparison_mask`). Cycles frames are
cached in :func:`experiments.gi_bias.cache_dir` (``$SLTWIN_GI_CACHE``).
"""
from __future__ import annotations

import functools

import numpy as np

from synth.effects.spec import Defocus, Effects
from synth.renderer.render import render
from synth.scenes.meshes import sphere_mesh
from synth.scenes.objects import Plane, Sphere
from synth.scenes.scene import DEFAULT_BALL_RADIUS_MM, Scene

from .gi_bias import EXPOSURE, BiasScene, _rect, _setup, cache_dir, cached_cycles

#: camera depth (mm) of the ball's front, where the camera is focused
FOCUS_MM = 822.2
#: aperture diameter (mm) of the comparison
APERTURE_MM = 80.0
WALL_Z_MM = -60.0


@functools.lru_cache(maxsize=4)
def defocus_scene(name: str = "ball-wall-dof", *, albedo: float = 0.8) -> BiasScene:
    """The scenes of the defocus comparison (module docstring); cached, treat as read-only."""
    from .errors import ExperimentError

    if name != "ball-wall-dof":
        raise ExperimentError(f"defocus_scene: unknown scene {name!r} (ball-wall-dof)")
    r = DEFAULT_BALL_RADIUS_MM
    V, F = sphere_mesh(r, 512, 256)
    wall_t, size = np.array([0.0, 0.0, WALL_Z_MM]), (600.0, 600.0)
    Vw, Fw = _rect(wall_t, np.eye(3), size, 4)
    return BiasScene(name, [Sphere("ball", np.eye(3), [0, 0, 0], albedo, r), Plane("wall", np.eye(3), wall_t, albedo, size)],
                     [(V, F, albedo, True), (Vw, Fw, albedo, False)], "ball r 25.4 mm, 34.6 mm before a wall")


SCENES = ("ball-wall-dof",)


def outline_band(geometry, width: int = 8) -> np.ndarray:
    """(H, W) bool: pixels within ``width`` 4-neighbour steps (city-block distance) of a pixel of another object (or of no
    object) or of other lighting (a cast shadow's edge: lit next to unlit)."""
    W, H = geometry.size
    obj = geometry.object_id.reshape(H, W).numpy() * 2 + geometry.lit.reshape(H, W).numpy()
    edge = np.zeros((H, W), bool)
    edge[:, 1:] |= obj[:, 1:] != obj[:, :-1]
    edge[:, :-1] |= obj[:, 1:] != obj[:, :-1]
    edge[1:] |= obj[1:] != obj[:-1]
    edge[:-1] |= obj[1:] != obj[:-1]
    out = edge.copy()
    for _ in range(width):
        grown = out.copy()
        grown[1:] |= out[:-1]
        grown[:-1] |= out[1:]
        grown[:, 1:] |= out[:, :-1]
        grown[:, :-1] |= out[:, 1:]
        out = grown
    return out


def cycles_dof_images(name: str, *, samples: int, aperture_mm: float | None, seed: int = 0, steps: int = 8,
                      threads: int = 2, focus_mm: float = FOCUS_MM, timeout: float = 3600,
                      projector_gamma: float = 1.0) -> dict:
    """Cycles' (K, H, W) linear images of ``name`` with thin-lens depth of field (``aperture_mm``
    None: pinhole), direct light only, the projector's pattern images raised to
    ``projector_gamma``; cached by scene, samples, aperture, focus, seed, steps, gamma."""
    from synth.blender_twin import render_in_blender

    ap = "pinhole" if aperture_mm is None else f"a{aperture_mm:g}_f{focus_mm:g}"
    g = "" if projector_gamma == 1.0 else f"_pg{projector_gamma:g}"
    def render():
        system, d_ref, patterns = _setup(steps)
        proj = np.stack([p.projector_image(system.projector.size, 0.5, 0.5) for p in patterns]) ** projector_gamma
        dof = None if aperture_mm is None else {"focus_mm": float(focus_mm), "aperture_mm": float(aperture_mm)}
        return render_in_blender(system, defocus_scene(name).meshes, proj, exposure=EXPOSURE,
                                 reference_distance_mm=d_ref, threads=threads, samples=samples, seed=seed,
                                 camera_dof=dof, timeout=timeout)

    return cached_cycles(cache_dir() / f"{name}_{ap}_s{samples}_seed{seed}_n{steps}{g}.npz", render)


def ours_dof_images(name: str, camera_defocus: Defocus | None, *, steps: int = 8, **effects):
    """Our (K, H, W) float64 linear images of ``name`` with ``camera_defocus`` (None: pinhole) and
    the render result."""
    system, d_ref, patterns = _setup(steps)
    sc = defocus_scene(name)
    eff = Effects(exposure=EXPOSURE, fringe_sampling="analytic", reference_distance_mm=d_ref,
                  camera_defocus=camera_defocus, **effects)
    res = render(Scene(system, sc.objects, patterns, eff), quantised=False)
    return res.images.numpy().astype(np.float64), res


def cycles_dof_bias(name: str = "ball-wall-dof", *, samples: int = 256, seeds=(0, 1), aperture_mm: float = APERTURE_MM,
                    focus_mm: float = FOCUS_MM, steps: int = 8) -> dict:
    """Cycles' defocus bias map (circular mean over ``seeds``), the per-seed maps, its pinhole
    stack and the seconds per defocused frame."""
    from .gi_bias import seeds_bias

    pin = cycles_dof_images(name, samples=1, aperture_mm=None, steps=steps)
    return seeds_bias(pin, [cycles_dof_images(name, samples=samples, aperture_mm=aperture_mm, focus_mm=focus_mm,
                                              seed=s, steps=steps) for s in seeds])


def ours_dof_bias(name: str = "ball-wall-dof", *, aperture_mm: float = APERTURE_MM, focus_mm: float = FOCUS_MM,
                  samples: int = 16, steps: int = 8) -> dict:
    """Our defocus bias map with the thin lens (``samples`` >= 1) or the old image blur
    (``samples`` 0), our pinhole stack, its geometry and the defocused render's time (s)."""
    from .gi_bias import bias_map

    pin, res0 = ours_dof_images(name, None, steps=steps)
    dof, res = ours_dof_images(name, Defocus(aperture_mm, focus_mm, 6, samples), steps=steps)
    return {"bias": bias_map(dof, pin), "direct": pin, "geometry": res0.geometry, "seconds": res.timings["total"],
            "plan": res.plan}


#: projector depth (mm) of the ball's front, where the projector is focused in the projector check
PROJECTOR_FOCUS_MM = 776.4


def projector_reference_bias(geometry, system, *, aperture_mm: float, focus_mm: float, radii: int = 24,
                             angles: int = 48, ball_radius_mm: float = DEFAULT_BALL_RADIUS_MM) -> np.ndarray:
    """An independent brute-force reference for the projector's thin lens on ``ball-wall-dof``:
    (H, W) unit-phase bias ``angle(sum_b w_b E_b exp(i Phi(u_b)) / E_0 exp(i Phi(u_0)))`` at the
    surface points of the camera's pinhole ``geometry``, the sum over a polar midpoint grid of
    ``radii`` x ``angles`` aperture points b (area weights), each with: its own DMD coordinate
    (the line from b through X to the focus plane; ideal projector), visibility from b (the ball
    as an analytic sphere for wall points, the facing test for ball points), Lambert cosine and
    inverse-square falloff from b. (The N-step phase of a sum of same-frequency sinusoids is the
    angle of the sum of their phasors.) NaN where the pinhole point is not lit."""
    from unwrap.patterns import absolute_phase

    cam, prj = system.camera, system.projector
    W, H = geometry.size
    ok = geometry.hit.numpy()
    Rc, tc = np.asarray(cam.R), np.asarray(cam.t)
    X = (geometry.points_cam.numpy()[ok] - tc) @ Rc  # world
    n = geometry.normals_cam.numpy()[ok] @ Rc
    on_ball = np.abs(np.linalg.norm(X, axis=1) - ball_radius_mm) < 1e-6
    Rp, tp = np.asarray(prj.R), np.asarray(prj.t)
    Cp = np.asarray(prj.center_world)
    r = (np.arange(radii) + 0.5) / radii * aperture_mm / 2
    a = (np.arange(angles) + 0.5) / angles * 2 * np.pi
    rr, aa = np.meshgrid(r, a, indexing="ij")
    pts = np.stack([rr.ravel() * np.cos(aa.ravel()), rr.ravel() * np.sin(aa.ravel())], 1)
    wts = rr.ravel() / rr.sum()

    def phasor(b):
        Cb = Cp + Rp.T @ np.array([b[0], b[1], 0.0])
        p = X @ Rp.T + tp - np.array([b[0], b[1], 0.0])
        x = p[:, 0] / p[:, 2] + b[0] / focus_mm
        y = p[:, 1] / p[:, 2] + b[1] / focus_mm
        u = prj.fx * x + prj.cx
        v = prj.fy * y + prj.cy
        inside = (u >= -0.5) & (u <= prj.width - 0.5) & (v >= -0.5) & (v <= prj.height - 0.5)
        d = Cb - X
        dist = np.linalg.norm(d, axis=1)
        dirn = d / dist[:, None]
        cos = (n * dirn).sum(1)
        # segment X -> Cb against the ball (wall points): |X + s dirn|^2 = r^2 for some 0 < s < dist
        bq = (X * dirn).sum(1)
        cq = (X * X).sum(1) - ball_radius_mm ** 2
        disc = bq * bq - cq
        s1 = -bq - np.sqrt(np.maximum(disc, 0))
        blocked = (~on_ball) & (disc > 0) & (s1 > 1e-6) & (s1 < dist)
        vis = inside & (cos > 0) & ~blocked
        return np.where(vis, cos / dist ** 2, 0.0) * np.exp(1j * absolute_phase(u, 1.0, prj.width))

    lens = sum(w * phasor(b) for w, b in zip(wts, pts))
    pin = phasor((0.0, 0.0))
    out = np.full(H * W, np.nan)
    lit = geometry.lit.numpy()[ok]
    out[np.flatnonzero(ok)[lit]] = np.angle(lens[lit] / pin[lit])
    return out.reshape(H, W)
