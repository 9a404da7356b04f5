"""The pattern stage: what the projector puts on each lit camera pixel, for the whole stack.

Given projector coordinates (u_p, v_p) of M lit pixels (from the geometry stage), returns the
projected value ``p`` (K, M) of every pattern, float64:

- fringes, analytic (default): ``A + B * a * cos(Phi - 2 pi n / N)`` with ``Phi`` from
  ``unwrap.patterns.absolute_phase``; ``cos Phi`` and ``sin Phi`` are computed once per
  (orientation, frequency) and each step is a linear combination of them. Projector defocus is
  the exact attenuation ``a = exp(-2 pi^2 sigma^2 (f / extent)^2)`` of a sinusoid by a Gaussian.
  With gamma, ``p**gamma`` (exact without defocus).
- image patterns (Gray code, user images, and fringes with ``fringe_sampling`` nearest/bilinear
  or gamma together with defocus): the projector image is sampled at (u_p, v_p), nearest
  (a DMD pixel is a sharp square: pixel ``floor(u + 0.5)``) or bilinear (Blender's linear
  texture lookup); projector defocus blurs the gamma-corrected image at a few levels and
  interpolates between them per pixel.
"""
from __future__ import annotations

import math

import numpy as np
import torch

from unwrap.patterns import absolute_phase, phase_shift

F64 = torch.float64


def sample_nearest(imgs: torch.Tensor, u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """imgs (K,H,W) at pixel coords (M,) -> (K,M); pixel ``floor(x + 0.5)``, clamped."""
    K, H, W = imgs.shape
    iu = torch.floor(u + 0.5).long().clamp(0, W - 1)
    iv = torch.floor(v + 0.5).long().clamp(0, H - 1)
    return imgs.reshape(K, -1)[:, iv * W + iu]


def sample_bilinear(imgs: torch.Tensor, u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """imgs (K,H,W) at pixel coords (M,) -> (K,M); pixel centres at integers, border clamped."""
    K, H, W = imgs.shape
    u = u.clamp(0, W - 1)
    v = v.clamp(0, H - 1)
    u0 = torch.floor(u).long().clamp(0, max(W - 2, 0))
    v0 = torch.floor(v).long().clamp(0, max(H - 2, 0))
    fu = (u - u0).to(imgs.dtype)
    fv = (v - v0).to(imgs.dtype)
    u1 = (u0 + 1).clamp(max=W - 1)
    v1 = (v0 + 1).clamp(max=H - 1)
    flat = imgs.reshape(K, -1)
    a = flat[:, v0 * W + u0]
    b = flat[:, v0 * W + u1]
    c = flat[:, v1 * W + u0]
    d = flat[:, v1 * W + u1]
    return (a * (1 - fu) + b * fu) * (1 - fv) + (c * (1 - fu) + d * fu) * fv


def _blur_levels(imgs: torch.Tensor, sigmas_uv: list) -> list:
    import kornia

    out = []
    for su, sv in sigmas_uv:
        if su < 1e-3 and sv < 1e-3:
            out.append(imgs)
            continue
        ku = 2 * int(math.ceil(3 * su)) + 1
        kv = 2 * int(math.ceil(3 * sv)) + 1
        b = kornia.filters.gaussian_blur2d(imgs[:, None], (kv, ku), (max(sv, 1e-3), max(su, 1e-3)),
                                           border_type="replicate")
        out.append(b[:, 0])
    return out


def _level_weights(s: torch.Tensor, levels: torch.Tensor):
    """Per-pixel linear interpolation between blur levels: (index (M,), weight of index+1 (M,))."""
    L = levels.numel()
    if L == 1 or float(levels[-1]) == 0:
        return torch.zeros_like(s, dtype=torch.long), torch.zeros_like(s)
    step = float(levels[1] - levels[0])
    x = (s / step).clamp(0, L - 1)
    i = torch.floor(x).long().clamp(max=L - 2)
    return i, x - i


def image_patterns(imgs: np.ndarray | torch.Tensor, u, v, *, sampling="nearest", gamma=1.0,
                   sigma=None, ratio_vu=1.0, levels=6) -> torch.Tensor:
    """Projector images (K,H_p,W_p) -> values (K,M) at (u, v); optional gamma and defocus.

    ``sigma`` (M,) is the blur along u_p (px); along v_p it is ``sigma * ratio_vu``.
    """
    imgs = torch.as_tensor(np.asarray(imgs) if not isinstance(imgs, torch.Tensor) else imgs, dtype=F64)
    if gamma != 1.0:
        imgs = imgs.clamp(min=0) ** gamma
    sample = sample_nearest if sampling == "nearest" else sample_bilinear
    if sigma is None or sigma.numel() == 0 or float(sigma.max()) < 1e-3:
        return sample(imgs, u, v)
    lv = torch.linspace(0, float(sigma.max()), levels, dtype=F64)
    blurred = _blur_levels(imgs, [(float(s), float(s) * ratio_vu) for s in lv])
    i, w = _level_weights(sigma, lv)
    out = torch.zeros((imgs.shape[0], u.shape[0]), dtype=F64)
    for k in range(levels):
        wk = torch.where(i == k, 1 - w, torch.zeros_like(w)) + torch.where(i + 1 == k, w, torch.zeros_like(w))
        m = wk > 0
        if bool(m.any()):
            out[:, m] += wk[m] * sample(blurred[k], u[m], v[m])
    return out


def analytic_fringes(specs, u, v, projector_size, *, A=0.5, B=0.5, gamma=1.0, sigma_uv=None) -> torch.Tensor:
    """Fringe PatternSpecs -> (K,M) values by the closed form (see the module docstring)."""
    W, H = projector_size
    out = torch.empty((len(specs), u.shape[0]), dtype=F64)
    groups: dict = {}
    for k, p in enumerate(specs):
        groups.setdefault((p.orientation, p.frequency), []).append(k)
    for (o, f), ks in groups.items():
        coord, extent = (u, W) if o == "v" else (v, H)
        phi = absolute_phase(coord, f, extent)
        c, s = torch.cos(phi), torch.sin(phi)
        amp = torch.full_like(c, B)
        if sigma_uv is not None:
            sig = sigma_uv[:, 0] if o == "v" else sigma_uv[:, 1]
            amp = amp * torch.exp(-2 * math.pi ** 2 * (sig * f / extent) ** 2)
        for k in ks:
            d = phase_shift(specs[k].step, specs[k].steps)
            out[k] = A + amp * (c * math.cos(d) + s * math.sin(d))
    if gamma != 1.0:
        out = out.clamp(min=0) ** gamma
    return out


def linear_model(patterns, u, v, projector_size, effects, sigma_uv=None):
    """The patterns that are linear in a few per-pixel basis rows (analytic fringes without
    gamma, white, black): ``p_k = coef[k] @ basis``.

    RETURNED VALUE: ``(indices, coef (K_lin, R) float64, basis (R, M) float64)``; basis row 0 is
    1, then ``a cos Phi`` and ``a sin Phi`` per (orientation, frequency); ``a`` is the defocus
    attenuation (1 without defocus).
    """
    W, H = projector_size
    A, B = effects.A, effects.B
    analytic = effects.fringe_sampling == "analytic" and effects.projector_gamma == 1.0
    idx = [k for k, p in enumerate(patterns)
           if p.kind in ("white", "black") or (p.kind == "fringe" and analytic)]
    rows = [torch.ones_like(u)]
    group_row: dict = {}
    for k in idx:
        p = patterns[k]
        if p.kind != "fringe" or (p.orientation, p.frequency) in group_row:
            continue
        coord, extent = (u, W) if p.orientation == "v" else (v, H)
        phi = absolute_phase(coord, p.frequency, extent)
        amp = 1.0
        if sigma_uv is not None:
            sig = sigma_uv[:, 0] if p.orientation == "v" else sigma_uv[:, 1]
            amp = torch.exp(-2 * math.pi ** 2 * (sig * p.frequency / extent) ** 2)
        group_row[(p.orientation, p.frequency)] = len(rows)
        rows += [amp * torch.cos(phi), amp * torch.sin(phi)]
    coef = torch.zeros((len(idx), len(rows)), dtype=F64)
    for i, k in enumerate(idx):
        p = patterns[k]
        if p.kind == "white":
            coef[i, 0] = 1.0
        elif p.kind == "fringe":
            r = group_row[(p.orientation, p.frequency)]
            d = phase_shift(p.step, p.steps)
            coef[i, 0], coef[i, r], coef[i, r + 1] = A, B * math.cos(d), B * math.sin(d)
    return idx, coef, torch.stack(rows)


def nonlinear_values(patterns, indices, u, v, projector_size, effects, sigma_uv=None, chunk: int = 8,
                     log=None) -> torch.Tensor:
    """Projected values (len(indices), M) float64 of the patterns outside the linear model."""
    out = torch.empty((len(indices), u.shape[0]), dtype=F64)
    gamma = effects.projector_gamma
    defocus = effects.projector_defocus
    analytic = [i for i, k in enumerate(indices) if patterns[k].kind == "fringe"
                and effects.fringe_sampling == "analytic" and sigma_uv is None]
    if analytic:
        out[analytic] = analytic_fringes([patterns[indices[i]] for i in analytic], u, v, projector_size,
                                         A=effects.A, B=effects.B, gamma=gamma)
    rest = [i for i in range(len(indices)) if i not in set(analytic)]
    if rest and log is not None and any(patterns[indices[i]].kind == "fringe" for i in rest):
        log.info("fringes: sampled from projector images (%s)",
                 "gamma with defocus" if effects.fringe_sampling == "analytic" else effects.fringe_sampling)
    sig = sigma_uv[:, 0] if sigma_uv is not None else None
    ratio = 1.0
    if sigma_uv is not None and float(sigma_uv[:, 0].max()) > 0:
        ratio = float(sigma_uv[:, 1].max() / sigma_uv[:, 0].max())
    for j in range(0, len(rest), chunk):
        ii = rest[j:j + chunk]
        specs = [patterns[indices[i]] for i in ii]
        imgs = np.stack([p.projector_image(projector_size, effects.A, effects.B) for p in specs])
        if all(p.kind == "fringe" for p in specs):
            sampling = "bilinear" if effects.fringe_sampling == "analytic" else effects.fringe_sampling
        else:
            sampling = effects.image_sampling
        out[ii] = image_patterns(imgs, u, v, sampling=sampling, gamma=gamma, sigma=sig, ratio_vu=ratio,
                                 levels=defocus.levels if defocus else 6)
    return out
