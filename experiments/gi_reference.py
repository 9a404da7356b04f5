"""Our global-illumination approximation (synth.effects.global_illumination) against Blender Cycles'
subsurface scattering on a plane (a thick slab: random-walk scattering needs a closed volume) and
a sphere, on the parity twin (ideal system, 160x120 camera).

Both renderers render each scene twice, direct light only and with subsurface scattering, and
each is compared with *itself*: so radiometric scale and Cycles' own conventions cancel, and what
is compared is what global illumination does to the fringes:

- contrast loss of a high frequency: median over interior pixels of ``(B/A)_gi / (B/A)_direct``
  (N-step modulation over background: independent of how much light each renderer's subsurface
  model returns in total), ours vs Cycles;
- phase bias of a low frequency: ``wrap(phi_gi - phi_direct)`` per pixel, ours vs Cycles (RMS of
  each, RMS of their difference, correlation).

Cycles' subsurface weight ``w`` is the fraction of the light that scatters under the surface
(Principled BSDF: diffuse (1 - w) + subsurface w), so our fraction is ``w``; Cycles' radius is a
mean free path of another profile than our Gaussian, so our scatter length sigma is fitted once,
on the plane's high-frequency contrast, and then used unchanged for the sphere and for the bias.
"""
from __future__ import annotations

import math

import numpy as np

from synth.blender_twin import render_in_blender
from synth.effects.spec import Effects, GlobalIllumination
from synth.renderer.render import render
from synth.scenes.meshes import sphere_mesh
from synth.scenes.objects import Mesh, Sphere
from synth.scenes.scene import DEFAULT_BALL_RADIUS_MM, Scene
from synth.scenes.sequence import phase_sequence

from .blender_parity import parity_system


def slab_mesh(half_mm: float = 400.0, thickness_mm: float = 40.0):
    """A closed box whose top face is z = 0 (world), ``2 half`` wide, ``thickness`` deep."""
    h, t = half_mm, thickness_mm
    V = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0],
                  [-h, -h, -t], [h, -h, -t], [h, h, -t], [-h, h, -t]], dtype=np.float64)
    F = np.array([[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6], [0, 4, 5], [0, 5, 1], [1, 5, 6], [1, 6, 2],
                  [2, 6, 7], [2, 7, 3], [3, 7, 4], [3, 4, 0]])
    return V, F


def _phase_contrast(stack):
    """N-step wrapped phase and contrast B/A (H,W) float64 (unwrap's least squares)."""
    from unwrap.phase_shift import wrapped_phase

    w = wrapped_phase(np.asarray(stack, dtype=np.float64), saturation=None, fill_invalid=False)
    A = np.asarray(w.A)
    return np.asarray(w.phase), np.where(A > 1e-6, np.asarray(w.B) / np.where(A > 1e-6, A, 1.0), 0.0)


def _interior(mask: np.ndarray, r: int = 3) -> np.ndarray:
    m = mask.copy()
    for _ in range(r):
        m[1:-1, 1:-1] &= m[:-2, 1:-1] & m[2:, 1:-1] & m[1:-1, :-2] & m[1:-1, 2:]
        m[0], m[-1], m[:, 0], m[:, -1] = False, False, False, False
    return m


def fit_sigma_mm(contrast: float, weight: float, nu_cyc_per_mm: float) -> float:
    """sigma (mm) of our Gaussian giving ``(1 - w) + w exp(-2 pi^2 sigma^2 nu^2) = contrast``."""
    t = (contrast - (1 - weight)) / weight
    t = min(max(t, 1e-6), 1 - 1e-9)
    return math.sqrt(-math.log(t) / (2 * math.pi ** 2 * nu_cyc_per_mm ** 2))


def gi_versus_cycles(kind: str, *, weight: float = 0.8, radius_mm: float = 4.0, sigma_mm: float | None = None,
                     frequencies=(1, 48), steps: int = 4, samples: int = 64, scale: int = 4, threads: int = 2,
                     python: str | None = None, albedo: float = 0.8) -> dict:
    """Render ``kind`` ("plane" or "sphere") with both renderers, direct and with subsurface
    scattering (Cycles: weight, radius; ours: fraction = weight, Gaussian ``sigma_mm``; None: fit
    it on this scene's highest frequency), and compare (module docstring)."""
    system = parity_system(scale)
    d_ref = float(np.linalg.norm(system.projector.center_world))
    exposure = 0.8
    if kind == "plane":
        V, F = slab_mesh()
        obj = Mesh("slab", np.eye(3), [0, 0, 0], V, F, albedo, False)
        meshes = [(V, F, albedo, False)]
    else:
        obj = Sphere("ball", np.eye(3), [0, 0, 0], albedo, DEFAULT_BALL_RADIUS_MM)
        V, F = sphere_mesh(DEFAULT_BALL_RADIUS_MM, 256, 128)
        meshes = [(V, F, albedo, True)]
    patterns = phase_sequence(("v",), tuple(frequencies), steps)
    proj = np.stack([p.projector_image(system.projector.size, 0.5, 0.5) for p in patterns])
    common = dict(exposure=exposure, reference_distance_mm=d_ref, threads=threads, python=python)
    cyc_direct = render_in_blender(system, meshes, proj, samples=1, **common)["images"]
    cyc_gi = render_in_blender(system, meshes, proj, samples=samples, bounces=4,
                               subsurface={"weight": weight, "radius_mm": radius_mm, "method": "RANDOM_WALK"},
                               **common)["images"]

    def ours(gi):
        eff = Effects(exposure=exposure, fringe_sampling="bilinear", reference_distance_mm=d_ref,
                      global_illumination=gi)
        return render(Scene(system, [obj], patterns, eff), quantised=False)

    direct = ours(None)
    g = direct.geometry
    H, W = system.camera.height, system.camera.width
    lit = _interior(g.lit.reshape(H, W).numpy())
    n = steps
    per_f = {}
    # local fringe frequency (cycles per mm on the surface) of the highest frequency, for the fit
    f_top = frequencies[-1]
    Wp = system.projector.width
    depth = float(np.nanmedian(g.depth.numpy()[g.lit.numpy()]))
    px_mm = system.camera.fx / depth  # camera px per mm at the surface (fronto-parallel)
    u = g.u_p.reshape(H, W).numpy()
    du = np.nanmedian(np.abs(np.gradient(np.where(lit, u, np.nan), axis=1))[lit])  # projector px per camera px
    nu_top = f_top / Wp * du * px_mm  # cycles per mm
    a_direct_c = {}
    for j, f in enumerate(frequencies):
        sl = slice(j * n, (j + 1) * n)
        pc, bc = _phase_contrast(cyc_direct[sl])
        pg, bg = _phase_contrast(cyc_gi[sl])
        a_direct_c[f] = (pc, bc, pg, bg)
    m_top = lit & (a_direct_c[f_top][1] > 1e-3)
    contrast_cycles_top = float(np.median(a_direct_c[f_top][3][m_top] / a_direct_c[f_top][1][m_top]))
    fitted = sigma_mm is None
    if fitted:
        sigma_mm = fit_sigma_mm(contrast_cycles_top, weight, nu_top)
    gi = ours(GlobalIllumination(subsurface=weight, scatter_mm=sigma_mm))
    a, b = direct.images.numpy().astype(np.float64), gi.images.numpy().astype(np.float64)
    for j, f in enumerate(frequencies):
        sl = slice(j * n, (j + 1) * n)
        po, bo = _phase_contrast(a[sl])
        pgo, bgo = _phase_contrast(b[sl])
        pc, bc, pg, bg = a_direct_c[f]
        m = lit & (bc > 1e-3) & (bo > 1e-3)
        bias_c = np.angle(np.exp(1j * (pg - pc)))[m]
        bias_o = np.angle(np.exp(1j * (pgo - po)))[m]
        per_f[f] = {"pixels": int(m.sum()),
                    "contrast_cycles": float(np.median(bg[m] / bc[m])), "contrast_ours": float(np.median(bgo[m] / bo[m])),
                    "bias_rms_cycles": float(np.sqrt(np.mean(bias_c ** 2))), "bias_rms_ours": float(np.sqrt(np.mean(bias_o ** 2))),
                    "bias_median_cycles": float(np.median(bias_c)), "bias_median_ours": float(np.median(bias_o)),
                    "bias_difference_rms": float(np.sqrt(np.mean((bias_c - bias_o) ** 2))),
                    "bias_correlation": float(np.corrcoef(bias_c, bias_o)[0, 1]) if bias_c.std() > 0 and bias_o.std() > 0 else 0.0}
    return {"kind": kind, "weight": weight, "radius_mm": radius_mm, "sigma_mm": sigma_mm, "sigma_fitted": fitted,
            "samples": samples, "size": system.camera.size, "nu_top_cycles_per_mm": nu_top, "per_frequency": per_f}
