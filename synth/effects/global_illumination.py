"""Global illumination, cheaply: subsurface scattering and interreflections as wide blurs of the
direct light over the surfaces.

Real plaster, skin or wax do not re-emit all the light where it arrived: a fraction travels under
the surface and leaves it millimetres away (subsurface scattering), and concave scenes send light
from one surface to another (interreflections). Both make the observed fringe the direct fringe
plus a blurred copy of it, which lowers the contrast of high-frequency patterns and, wherever the
light under the blur is not symmetric (shading gradients, silhouettes, shadows), biases the phase
of low-frequency ones (Gupta & Nayar, "Micro Phase Shifting", CVPR 2012; Chen et al., "Modulated
phase-shifting for 3D scanning", CVPR 2008).

Model (per camera pixel x on object o, linear radiance L before the camera's own blur and noise):

    L_sub(x)  = (1 - s_o) L(x) + s_o * <L>_o(x; sigma_o)        (light stays on the object)
    L_out(x)  = L_sub(x) + r * <L_sub>_all(x; sigma_r)          (light from nearby surfaces)

``<L>_o(x; sigma)`` is the Gaussian-weighted mean of L over the pixels of object o (a normalised
convolution: the blur of ``L * mask_o`` over the blur of ``mask_o``), and ``<L>_all`` the same over
every surface pixel. ``s_o`` is the object's subsurface fraction (its "material"), sigma_o its
scattering length in mm turned into camera pixels at the object's median depth
(``sigma_px = scatter_mm * f_px / depth``); the subsurface term conserves energy on a uniform
plane. ``r`` is the interreflection fraction (added light). The blurs are wide (several pixels),
so they run on a copy reduced by an integer factor (area average), blurred by kornia and enlarged
bilinearly.

The approximation ignores foreshortening of the spread on tilted surfaces, the exact diffusion
profile (Gaussian instead of the dipole's) and the geometry of the interreflection (no form
factors); ``tests/test_synth_global_illumination.py`` measures what that costs against Blender
Cycles' random-walk subsurface scattering on a plane and a sphere.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F_nn

from ..errors import SynthError

#: Blurs run on a copy reduced so that sigma is at least this many (reduced) pixels.
_MIN_SIGMA_REDUCED = 2.0


def _blur(x: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """Gaussian blur of (C, H, W) with sigma (px), through an area-reduced copy for wide sigmas."""
    import kornia

    C, H, W = x.shape
    if sigma_px < 0.3:
        return x
    d = max(1, int(sigma_px // _MIN_SIGMA_REDUCED))
    small = F_nn.avg_pool2d(x[None], d, d, ceil_mode=True, count_include_pad=False)[0] if d > 1 else x
    s = sigma_px / d
    k = 2 * int(math.ceil(3 * s)) + 1
    blurred = kornia.filters.gaussian_blur2d(small[None], (k, k), (s, s), border_type="constant")[0]
    if d > 1:
        blurred = F_nn.interpolate(blurred[None], scale_factor=d, mode="bilinear", align_corners=False)[0]
        blurred = blurred[:, :H, :W]
    return blurred


def _normalised_mean(rows: torch.Tensor, mask: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """Gaussian-weighted mean of rows (C, H, W) over the pixels of ``mask`` (H, W)."""
    m = mask.to(rows.dtype)
    num = _blur(torch.cat([rows * m, m[None]]), sigma_px)
    den = num[-1].clamp(min=1e-6)
    return num[:-1] / den


def apply_global_illumination(rows: torch.Tensor, geometry, gi, f_px: float, log=None) -> torch.Tensor:
    """Apply the model of the module docstring to linear images or basis rows ``rows`` (C, H*W)
    (any C: the renderer passes its basis rows, since the model is linear). Returns (C, H*W)."""
    W, H = geometry.size
    C = rows.shape[0]
    x = rows.reshape(C, H, W)
    obj = geometry.object_id.reshape(H, W)
    depth = geometry.depth.reshape(H, W)
    n_obj = int(obj.max()) + 1 if obj.numel() else 0
    out = x
    done = []
    if n_obj > 0:
        materials = gi.materials(n_obj)
        out = x.clone()
        for o, (s, mm) in enumerate(materials):
            m = obj == o
            if s <= 0 or not bool(m.any()):
                continue
            z = float(depth[m].median())
            sigma = mm * f_px / z
            mean = _normalised_mean(x, m, sigma)
            out[:, m] = (1 - s) * x[:, m] + s * mean[:, m]
            done.append(f"object {o}: fraction {s:.3g}, {mm:.3g} mm = {sigma:.1f} px")
    if gi.interreflection > 0 and n_obj > 0:
        hit = obj >= 0
        zmed = float(depth[hit].median())
        sigma = gi.interreflection_mm * f_px / zmed
        mean = _normalised_mean(out, hit, sigma)
        out = out.clone() if out is x else out
        out[:, hit] += gi.interreflection * mean[:, hit]
        done.append(f"interreflection {gi.interreflection:.3g}, {gi.interreflection_mm:.3g} mm = {sigma:.1f} px")
    if log is not None:
        log.info("global illumination: %s", "; ".join(done) if done else "skipped (zero fractions)")
    return out.reshape(C, H * W)


def validate_materials(per_object, key: str = "effects.global_illumination.per_object") -> tuple:
    """``[[fraction, scatter_mm], ...]`` -> tuple of float pairs (SynthError naming the key)."""
    out = []
    for i, pair in enumerate(per_object):
        try:
            s, mm = (float(v) for v in pair)
        except (TypeError, ValueError):
            raise SynthError(f"{key}[{i}]: expected [fraction, scatter_mm], got {pair!r}") from None
        if not (0.0 <= s <= 1.0) or not (mm > 0 and math.isfinite(mm)):
            raise SynthError(f"{key}[{i}]: fraction in [0, 1] and scatter_mm > 0 expected, got {pair!r}")
        out.append((s, mm))
    return tuple(out)
