"""Diffuse interreflection from the scene's own geometry, with Lambertian form factors.

Light that reaches a camera-visible point x indirectly, from another surface point y the
projector lights, carries the pattern value of *y*'s projector column: at a low fringe frequency
that mixing keeps a coherent phase and biases the decoded phase, most where x sees a bright
surface close by whose projector column differs (beside an object's outline on the wall behind
it, in concave corners). This module computes that light physically, one bounce exactly (up to
the patch discretisation) and optionally a second one on the coarse patches.

Radiometry. Our camera value of a Lambertian point is proportional to its radiance,
``value = k L`` with ``L = rho E / pi`` (E: irradiance). One bounce from patches y_j of area A_j:

    value_1(x) = rho(x) / pi * sum_j value_0(y_j) A_j cos(theta_x) cos(theta_j) V(x, y_j) / r^2

(``value_0``: y_j's direct value without camera vignetting; the point-to-disc form factor
``A cos cos / (pi r^2 + A)`` replaces ``A cos cos / (pi r^2)``, which stays finite at r -> 0),
times x's vignetting. The renderer passes its pattern basis rows (or the nonlinear patterns'
values) evaluated at the patches; the sum is linear in them, so one transport serves the stack.

Patches: the surfaces the projector lights are exactly the nearest hits of projector rays, so
the patches are sampled *from the projector* on a grid of ``patch_px / refine`` projector
pixels (fine patches, each integrating the pattern over its footprint; rays of solid angle ``dOmega``, patch area ``dOmega d^2 / cos_p``, so a
patch's emitted power ``value_0 A`` does not depend on the grazing angle), with the projector's
own shadowing exact (only the nearest hit is lit) and surfaces the camera never sees included.
Fine patches are grouped per (``patch_px`` cell, object) into coarse patches (area-weighted
position and normal, summed area and power). Each receiver gathers from the coarse patches,
except from those closer than ``near`` coarse sizes, which it replaces by their fine children.

Visibility between x and y_j: exact segment tests against every sphere and plane (bounded or
not) other than a convex receiver's or emitter's own object (a convex surface cannot block a
pair both of whose cosines are positive). Meshes: with ``mesh_visibility`` (default) every
pair is tested against the meshes by synth.effects._segment_kernel (a uniform
grid, 3-D DDA, Moeller-Trumbore; a mesh above 8000 triangles is replaced by its vertex
clustering at 1/30 of its extent and the tolerance at both ends grows to that cell); without
it (the plan line says so) a concave mesh's self-shadowing of indirect light and a mesh standing
between two other surfaces are not modelled, only the cosine terms (an over-estimate there).

Second bounce (``bounces = 2``): the coarse patches gather the first bounce the same way (coarse
emitters only) and re-emit it, ``rho(y) / pi`` times their irradiance, to the receivers; surfaces
the projector does not light are not re-emitters (their second-bounce light is dropped).

Frames: world mm. Shapes: receivers M (camera pixels that see a surface), patches P, rows Q.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..scenes.objects import Mesh, Plane, Rays, Sphere

F64 = torch.float64
_PAIR_CHUNK = 1 << 22  # receiver x patch pairs evaluated at once (~32 MB a float64 temporary)


@dataclass
class Patches:
    """Surface patches lit by the projector (world mm): position (P,3), normal (P,3) facing the
    projector, area (P,) mm^2, albedo (P,), object id (P,), projector pixel (u, v) (P,2),
    ``power`` (P,) = value_0 / p x area (the direct value per unit pattern value, times area),
    z_prj (P,) projector depth (mm)."""

    X: torch.Tensor
    n: torch.Tensor
    area: torch.Tensor
    albedo: torch.Tensor
    obj: torch.Tensor
    uv: torch.Tensor
    power: torch.Tensor
    z_prj: torch.Tensor


def interacting_pairs(objects) -> list:
    """(receiver object, emitter object) index pairs that can exchange light: every ordered pair
    of distinct objects and each non-convex object with itself."""
    n = len(objects)
    return [(a, b) for a in range(n) for b in range(n) if a != b or not objects[a].convex]


def skip_reason(objects) -> str | None:
    """Why interreflection cannot change this scene's image (None: it can)."""
    if not objects:
        return "empty scene"
    if not interacting_pairs(objects):
        return f"a single convex {objects[0].kind} cannot light itself"
    return None


def _projector_grid(prj, step: float, use_distortion: bool):
    """Projector pixel centres on a grid of ``step`` px covering the image, their undistorted
    normalised coordinates and solid angles: (uv (P,2), xy (P,2), dOmega (P,), grid shape)."""
    from calib.distortion import undistort

    W, H = prj.size
    us = np.arange(step / 2, W, step) - 0.5
    vs = np.arange(step / 2, H, step) - 0.5
    V, U = np.meshgrid(vs, us, indexing="ij")
    uv = np.stack([U.ravel(), V.ravel()], 1)
    xyd = prj.pixels_to_normalized(uv)
    if use_distortion and prj.distortion.size and np.any(prj.distortion):
        xy, ok = undistort(xyd, prj.distortion)
        xy = np.where(ok[:, None], xy, np.nan)
    else:
        xy = xyd
    g = xy.reshape(len(vs), len(us), 2)
    # Jacobian of (u, v) -> (x, y) by differences over the grid (exact without distortion)
    if len(us) > 1 and len(vs) > 1:
        dxu = np.gradient(g, axis=1) / step
        dxv = np.gradient(g, axis=0) / step
        jac = np.abs(dxu[..., 0] * dxv[..., 1] - dxu[..., 1] * dxv[..., 0]).ravel()
    else:
        jac = np.full(len(uv), 1.0 / (prj.fx * prj.fy))
    domega = jac * step * step / (1.0 + (xy ** 2).sum(1)) ** 1.5
    return uv, xy, domega, (len(vs), len(us))


def sample_patches(scene, step: float) -> Patches:
    """Fine patches: nearest hits of projector rays on a ``step`` px grid (module docstring)."""
    from ..renderer.geometry import nearest_surface

    eff, prj = scene.effects, scene.system.projector
    use_dist = eff.projector_distortion and bool(np.any(prj.distortion))
    uv, xy, domega, _ = _projector_grid(prj, step, use_dist)
    ok = np.isfinite(xy).all(1)
    uv, xy, domega = uv[ok], xy[ok], domega[ok]
    R = torch.tensor(prj.R)
    xy_t = torch.from_numpy(np.ascontiguousarray(xy))
    d = xy_t @ R[:2] + R[2]
    d = d / torch.linalg.norm(d, dim=1, keepdim=True)
    C = torch.tensor(prj.center_world)
    rays = Rays(C, d, xy_t, R, torch.tensor(prj.t), step / max(prj.fx, prj.fy), "projector")
    t, obj, n, local = nearest_surface(scene.objects, rays)
    hit = torch.isfinite(t)
    t, obj, n, local, d = t[hit], obj[hit], n[hit], local[hit], d[hit]
    uv_t = torch.from_numpy(uv)[hit]
    dom = torch.from_numpy(domega)[hit]
    X = C + t[:, None] * d
    cos_p = -(n * d).sum(1)
    n = torch.where((cos_p < 0)[:, None], -n, n)  # two-sided: the lit side faces the projector
    cos_p = cos_p.abs().clamp(min=0.05)
    area = dom * t * t / cos_p
    albedo = torch.zeros(t.numel(), dtype=F64)
    foot = torch.sqrt(area)
    for i, o in enumerate(scene.objects):
        m = obj == i
        if bool(m.any()):
            albedo[m] = o.albedo(local[m], foot[m])
    shade = cos_p if eff.shading == "lambert" else torch.ones_like(cos_p)
    if eff.falloff:
        d_ref = eff.reference_distance_mm or float(np.linalg.norm(prj.center_world))
        shade = shade * (d_ref / t) ** 2
    power = eff.exposure * albedo * shade * area
    z_prj = t * (d @ R[2])
    return Patches(X, n, area, albedo, obj, uv_t, power, z_prj)


def coarse_patches(fine: Patches, step: float, refine: int):
    """Group fine patches per (coarse cell, object): (coarse Patches, child -> coarse index (P_f,))."""
    cu = torch.div(fine.uv[:, 0] + 0.5, step * refine, rounding_mode="floor").to(torch.int64)
    cv = torch.div(fine.uv[:, 1] + 0.5, step * refine, rounding_mode="floor").to(torch.int64)
    key = (cv * 100000 + cu) * 64 + fine.obj
    uniq, parent = torch.unique(key, return_inverse=True)
    P = uniq.numel()

    def wsum(x, w):
        out = torch.zeros((P, *x.shape[1:]), dtype=F64)
        return out.index_add_(0, parent, x * (w[:, None] if x.ndim > 1 else w))

    area = torch.zeros(P, dtype=F64).index_add_(0, parent, fine.area)
    X = wsum(fine.X, fine.area) / area[:, None]
    n = wsum(fine.n, fine.area)
    n = n / torch.linalg.norm(n, dim=1, keepdim=True).clamp(min=1e-300)
    power = torch.zeros(P, dtype=F64).index_add_(0, parent, fine.power)
    albedo = wsum(fine.albedo, fine.area) / area
    obj = torch.zeros(P, dtype=torch.int64).index_copy_(0, parent, fine.obj)
    uv = wsum(fine.uv, fine.area) / area[:, None]
    z = wsum(fine.z_prj, fine.area) / area
    return Patches(X, n, area, albedo, obj, uv, power, z), parent


def _occluded_dense(objects, skip, X, Y) -> torch.Tensor | None:
    """(r, e) bool: the open segment between receiver X[i] (r,3) and emitter Y[j] (e,3) meets a
    sphere or plane of ``objects`` whose index is not in ``skip``; None when none is tested.
    Broadcast through dot products (no (r, e, 3) temporaries)."""
    out = None
    eps = 1e-7
    for i, o in enumerate(objects):
        if i in skip or not isinstance(o, (Sphere, Plane)):
            continue
        if isinstance(o, Sphere):
            fx, fy = X - o.t, Y - o.t  # segment p(s) = X + s (Y - X); f = X - c
            fxx = (fx * fx).sum(1)[:, None]
            fyy = (fy * fy).sum(1)[None, :]
            fxy = fx @ fy.T
            a = (fxx + fyy - 2 * fxy).clamp(min=1e-300)
            b = fxy - fxx
            c = fxx - o.radius ** 2
            disc = b * b - a * c
            sq = torch.sqrt(disc.clamp(min=0))
            occ = (disc > 0) & ((-b - sq) < (1 - eps) * a) & ((-b + sq) > eps * a)
        else:
            nz = o.R[:, 2]
            sx, sy = ((X - o.t) @ nz)[:, None], ((Y - o.t) @ nz)[None, :]
            occ = (sx * sy) < 0
            if o.size_mm is not None:
                s = sx / torch.where(occ, sx - sy, torch.ones_like(sx * sy))
                for ax, half in ((0, o.size_mm[0] / 2), (1, o.size_mm[1] / 2)):
                    e = o.R[:, ax]
                    px, py = ((X - o.t) @ e)[:, None], ((Y - o.t) @ e)[None, :]
                    occ &= (px + s * (py - px)).abs() <= half
        out = occ if out is None else out | occ
    return out


def _kernel_dense(Xr, nr, Ye, ne, area):
    """(r, e) ``cos_r cos_e / (r^2 + A / pi)`` and r^2 for every receiver x emitter pair
    (receiver (r,3) points and normals, emitter (e,3) points, normals, areas (e,)). The
    point-to-disc form factor is ``A / pi`` times it; the receiver's rho / pi and the emitter's
    value x area are applied outside: ``value_1 = rho_r / pi * sum_e (value_e A_e) k_e``.

    Three matrix products with augmented vectors (coordinates centred on the emitters' mean to
    keep r^2 = |x|^2 + |y|^2 - 2 x.y accurate), then in-place element-wise operations."""
    o = Ye.mean(0)
    X, Y = Xr - o, Ye - o
    one_r, one_e = torch.ones_like(X[:, :1]), torch.ones_like(Y[:, :1])
    xx, yy = (X * X).sum(1, keepdim=True), (Y * Y).sum(1, keepdim=True)
    r2 = torch.cat([X, xx, one_r], 1) @ torch.cat([-2 * Y, one_e, yy], 1).T
    r2.clamp_(min=1e-300)
    k = torch.cat([nr, -(nr * X).sum(1, keepdim=True)], 1) @ torch.cat([Y, one_e], 1).T   # r cos_r
    k.clamp_(min=0)
    ce = torch.cat([X, one_r], 1) @ torch.cat([ne, -(ne * Y).sum(1, keepdim=True)], 1).T  # r cos_e
    k.mul_(ce.clamp_(min=0)).div_(r2).clamp_(max=1.0)  # cos_r cos_e <= 1 (coincident points: 0 / 0)
    return k.div_(torch.add(r2, area[None, :], alpha=1 / math.pi)), r2


def _mesh_occluder(objects, max_triangles: int = 8000, divisions: int = 30):
    """(SegmentGrid over the meshes' world triangles, end tolerance mm) or None without meshes. A
    mesh larger than ``max_triangles`` is replaced by its vertex clustering at 1/``divisions``
    of its largest extent (the tolerance then grows to that cell, so a segment leaving a surface does
    not hit the coarser proxy of that same surface)."""
    from ._segment_kernel import SegmentGrid, decimate

    tris, eps = [], 0.02
    for o in objects:
        if not isinstance(o, Mesh):
            continue
        V = (o.V @ o.R.T + o.t).numpy()
        F = o.F.numpy()
        if F.shape[0] > max_triangles:
            cell = float(np.ptp(V, axis=0).max()) / divisions
            V, F = decimate(V, F, cell)
            eps = max(eps, cell)
        tris.append(V[F])
    if not tris:
        return None
    return SegmentGrid(np.concatenate(tris)), eps


class Transport:
    """The light transport from patches to receivers of one scene pose (module docstring).

    ``apply(values_fine)`` takes the pattern values at the fine patches (Q, P_f) (basis rows or
    pattern values, before the patch's power) and returns the indirect values (Q, M) at the
    receivers, before the receiver's vignetting. Receiver x coarse-patch blocks are dense (chunks
    of at most ``_PAIR_CHUNK`` pairs): the kernel by dot products, then one matrix product."""

    def __init__(self, scene, Xr, nr, rho_r, obj_r, ir):
        self.objects = scene.objects
        step = ir.patch_px / ir.refine
        self.fine = sample_patches(scene, step)
        self.coarse, self.parent = coarse_patches(self.fine, step, ir.refine)
        self.Xr, self.nr, self.rho_r, self.obj_r = Xr, nr, rho_r, obj_r
        self.ir = ir
        self.pairs = interacting_pairs(scene.objects)
        self.stats = {"fine patches": self.fine.X.shape[0], "coarse patches": self.coarse.X.shape[0],
                      "far pairs": 0, "near pairs (fine)": 0, "occluded pairs": 0}
        #: the meshes as occluders (synth.effects._segment_kernel), when ``mesh_visibility``
        self.occluder = _mesh_occluder(scene.objects) if ir.mesh_visibility else None
        order = torch.argsort(self.parent, stable=True)  # children of each coarse patch (CSR)
        counts = torch.bincount(self.parent, minlength=self.coarse.X.shape[0])
        self.child_order, self.child_start, self.child_count = order, torch.cumsum(counts, 0) - counts, counts

    def towards(self, Xr, nr, rho_r, obj_r) -> "Transport":
        """This transport (the same patches and occluders) towards other receivers (world mm, as
        the constructor's): a shallow copy whose pair counts start at 0."""
        import copy

        t = copy.copy(self)
        t.Xr, t.nr, t.rho_r, t.obj_r = Xr, nr, rho_r, obj_r
        t.stats = {**self.stats, "far pairs": 0, "near pairs (fine)": 0, "occluded pairs": 0}
        return t

    def _skip(self, a, b):
        return {i for i in (a, b) if self.objects[i].convex}

    def _gather(self, Xr, nr, obj_r, src_c, src_f, *, refine: bool) -> torch.Tensor:
        """(Q, r) sum over the coarse patches (their fine children where near when ``refine``) of
        kernel x src (value x area) at receivers (Xr, nr, obj_r)."""
        c, f = self.coarse, self.fine
        near_r2 = (self.ir.near ** 2) * c.area
        out = torch.zeros((src_c.shape[0], Xr.shape[0]), dtype=F64)
        for a, b in self.pairs:
            ri = torch.nonzero(obj_r == a).squeeze(1)
            ei = torch.nonzero(c.obj == b).squeeze(1)
            if ri.numel() == 0 or ei.numel() == 0:
                continue
            skip = self._skip(a, b)
            Ye, ne, Ae, Se = c.X[ei], c.n[ei], c.area[ei], src_c[:, ei]
            rows = max(1, _PAIR_CHUNK // ei.numel())
            for j in range(0, ri.numel(), rows):
                rr = ri[j:j + rows]
                k, r2 = _kernel_dense(Xr[rr], nr[rr], Ye, ne, Ae)
                near = r2 < near_r2[ei][None, :] if refine else None
                if near is not None:
                    if bool(near.any()):
                        k.masked_fill_(near, 0.0)
                    else:
                        near = None
                occ = _occluded_dense(self.objects, skip, Xr[rr], Ye)
                if occ is not None:
                    occ &= k > 0
                    self.stats["occluded pairs"] += int(occ.sum())
                    k.masked_fill_(occ, 0.0)
                if self.occluder is not None:
                    self._mesh_visibility(k, Xr[rr], Ye)
                self.stats["far pairs"] += int(torch.count_nonzero(k))
                out[:, rr] += Se @ k.T
                if near is not None:
                    out += self._near(Xr, nr, rr, ei, near, src_f, skip)
        return out

    def _mesh_visibility(self, k, Xr, Ye):
        """Zero the pairs of the dense block ``k`` (r, e) that a mesh blocks (in place)."""
        i, j = torch.nonzero(k > 0, as_tuple=True)
        if i.numel() == 0:
            return
        grid, eps = self.occluder
        occ = torch.from_numpy(grid.occluded(Xr[i].numpy(), Ye[j].numpy(), eps, eps))
        k[i[occ], j[occ]] = 0.0
        self.stats["occluded pairs"] += int(occ.sum())

    def _near(self, Xr, nr, rr, ei, near, src_f, skip) -> torch.Tensor:
        """Near pairs, each coarse patch replaced by its fine children: (Q, r_all) additions."""
        f = self.fine
        i, j = torch.nonzero(near, as_tuple=True)
        R_, E_ = rr[i], ei[j]
        cnt = self.child_count[E_]
        Rn = torch.repeat_interleave(R_, cnt)
        first = torch.repeat_interleave(self.child_start[E_] - (torch.cumsum(cnt, 0) - cnt), cnt)
        Fi = self.child_order[torch.arange(Rn.numel()) + first]
        d = f.X[Fi] - Xr[Rn]
        r2 = (d * d).sum(1)
        cr = (nr[Rn] * d).sum(1).clamp(min=0)
        ce = -(f.n[Fi] * d).sum(1)
        k = (cr * ce.clamp(min=0) / r2.clamp(min=1e-300)).clamp(max=1.0) / (r2 + f.area[Fi] / math.pi)
        pos = torch.nonzero(k > 0).squeeze(1)
        Rn, Fi, k = Rn[pos], Fi[pos], k[pos]
        occ = _occluded_pairs(self.objects, skip, Xr[Rn], f.X[Fi])
        if self.occluder is not None and Rn.numel():
            grid, eps = self.occluder
            m_occ = torch.from_numpy(grid.occluded(Xr[Rn].numpy(), f.X[Fi].numpy(), eps, eps))
            occ = m_occ if occ is None else occ | m_occ
        if occ is not None:
            self.stats["occluded pairs"] += int(occ.sum())
            k = torch.where(occ, torch.zeros_like(k), k)
        self.stats["near pairs (fine)"] += int((k > 0).sum())
        out = torch.zeros((src_f.shape[0], Xr.shape[0]), dtype=F64)
        return out.index_add_(1, Rn, src_f[:, Fi] * k)

    def apply(self, values_fine: torch.Tensor) -> torch.Tensor:
        f, c = self.fine, self.coarse
        src_f = values_fine * f.power                                    # value x area
        src_c = torch.zeros((values_fine.shape[0], c.X.shape[0]), dtype=F64)
        src_c.index_add_(1, self.parent, src_f)
        out = self._gather(self.Xr, self.nr, self.obj_r, src_c, src_f, refine=True)
        if self.ir.bounces >= 2:
            # first bounce at the coarse patches (value = rho / pi x gathered), re-emitted from
            # them (value x area) to the receivers; coarse only: the second bounce is smooth
            b1 = self._gather(c.X, c.n, c.obj, src_c, src_f, refine=False) * (c.albedo / math.pi)
            out += self._gather(self.Xr, self.nr, self.obj_r, b1 * c.area, None, refine=False)
        return out * (self.rho_r / math.pi)


def _occluded_pairs(objects, skip, X, Y) -> torch.Tensor | None:
    """(N,) bool for matched pairs X[i] -> Y[i]: the diagonal of :func:`_occluded_dense`."""
    if not any(isinstance(o, (Sphere, Plane)) and k not in skip for k, o in enumerate(objects)):
        return None
    d = Y - X
    eps = 1e-7
    out = torch.zeros(X.shape[0], dtype=torch.bool)
    for i, o in enumerate(objects):
        if i in skip:
            continue
        if isinstance(o, Sphere):
            fv = X - o.t
            a = (d * d).sum(1).clamp(min=1e-300)
            b = (fv * d).sum(1)
            c = (fv * fv).sum(1) - o.radius ** 2
            disc = b * b - a * c
            sq = torch.sqrt(disc.clamp(min=0))
            out |= (disc > 0) & ((-b - sq) < (1 - eps) * a) & ((-b + sq) > eps * a)
        elif isinstance(o, Plane):
            nz = o.R[:, 2]
            sx, sy = (X - o.t) @ nz, (Y - o.t) @ nz
            cross = (sx * sy) < 0
            if o.size_mm is not None:
                s = sx / torch.where(cross, sx - sy, torch.ones_like(sx))
                p = (X + s[:, None] * d - o.t) @ o.R
                cross &= (p[:, 0].abs() <= o.size_mm[0] / 2) & (p[:, 1].abs() <= o.size_mm[1] / 2)
            out |= cross
    return out


def patch_values(scene, fine: Patches, other: list) -> tuple[torch.Tensor, int]:
    """The pattern values the fine patches emit: (values (R + len(other), P_f) float64, R): the
    linear patterns' R basis rows, then the nonlinear patterns ``other`` (indices into
    ``scene.patterns``). Each fine patch integrates the pattern over its projector footprint (a
    box of ``patch_px / refine`` px): a Gaussian of the box's variance step^2 / 12, with the
    projector's defocus if any (patterns finer than the patches average out instead of
    aliasing)."""
    from ..renderer.geometry import defocus_sigma
    from ..renderer.projection import linear_model, nonlinear_values

    eff, prj = scene.effects, scene.system.projector
    ir = eff.interreflection
    step = ir.patch_px / ir.refine
    sig = torch.full((fine.X.shape[0], 2), step / math.sqrt(12.0), dtype=F64)
    if eff.projector_defocus is not None:
        sig = torch.sqrt(sig ** 2 + torch.stack([defocus_sigma(eff.projector_defocus, prj.fx, fine.z_prj),
                                                 defocus_sigma(eff.projector_defocus, prj.fy, fine.z_prj)], 1) ** 2)
    u, v = fine.uv[:, 0], fine.uv[:, 1]
    _, _, basis = linear_model(scene.patterns, u, v, prj.size, eff, sig)
    if not other:
        return basis, basis.shape[0]
    return torch.cat([basis, nonlinear_values(scene.patterns, other, u, v, prj.size, eff, sig)]), basis.shape[0]


def apply_interreflection(full: torch.Tensor, nl: torch.Tensor | None, scene, geometry, other: list,
                          log=None) -> tuple[torch.Tensor, torch.Tensor | None, dict]:
    """Add the indirect light to the renderer's basis rows ``full`` (R + 1, N) float32 (row 0:
    ambient, rows 1..R: the linear patterns' basis rows scaled by the direct radiance) and to the
    nonlinear patterns' images ``nl`` (len(other), N) (or None), at every pixel that sees a
    surface (lit or in a cast shadow). Returns (full, nl, stats)."""
    from ..renderer.geometry import camera_rays

    eff, cam = scene.effects, scene.system.camera
    ir = eff.interreflection
    hit = torch.nonzero(geometry.hit).squeeze(1)
    vign = torch.ones(hit.numel(), dtype=F64)
    if eff.vignetting > 0:
        rays, _ = camera_rays(cam, eff.camera_distortion and bool(np.any(cam.distortion)))
        rx = torch.nan_to_num(rays.xy[hit], nan=0.0)
        vign = 1.0 - eff.vignetting * (1.0 - 1.0 / (1.0 + (rx ** 2).sum(1)) ** 2)
    shared = getattr(geometry, "shared_indirect", None)
    if shared is not None:  # synth.effects.lens_indirect: one aperture point of the thin lens
        add, R, stats = shared.rows(geometry, hit)
    else:
        Rc, tc = torch.tensor(cam.R), torch.tensor(cam.t)
        Xr = (geometry.points_cam[hit] - tc) @ Rc
        nr = geometry.normals_cam[hit] @ Rc
        T = Transport(scene, Xr, nr, geometry.albedo[hit], geometry.object_id[hit], ir)
        values, R = patch_values(scene, T.fine, other if nl is not None else [])
        add = T.apply(values)
        stats = T.stats
    add = add * vign
    full = full.clone()
    full[1:, hit] += add[:R].to(full.dtype)
    if nl is not None and other:
        nl = nl.clone()
        nl[:, hit] += add[R:].to(nl.dtype)
    if log is not None and shared is not None:
        log.info("interreflection: %s", shared.describe())
    elif log is not None:
        s = stats
        log.info("interreflection: %d bounce(s), %d fine / %d coarse patches (%.3g / %.3g projector px), "
                 "%d far + %d near pair(s), %d occluded (spheres and planes tested; meshes: %s)",
                 ir.bounces, s["fine patches"], s["coarse patches"], ir.patch_px / ir.refine, ir.patch_px,
                 s["far pairs"], s["near pairs (fine)"], s["occluded pairs"],
                 ("traced (segment grid)" if T.occluder is not None else "none in the scene")
                 if ir.mesh_visibility else "not tested")
    return full, nl, stats
