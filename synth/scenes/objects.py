"""Scene objects: analytic plane, board and sphere; triangle meshes (files and procedural).

Every object has a pose ``X_world = R @ X_obj + t`` (mm), a uniform albedo or a printed texture,
and ``intersect(rays)`` returning, per ray, the distance along the unit ray (inf: no hit), the
unit surface normal in the world frame and the hit point in the object frame. All float64.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from .boards import BoardTexture
from ..errors import SynthError
from ..renderer.raycast import nearest_hits, numba_engine_available, triangle_areas

F64 = torch.float64


@dataclass
class Rays:
    """Rays leaving one device centre.

    - origin: (3,) world position of the device centre (mm).
    - dirs: (N,3) unit directions in the world frame.
    - xy: (N,2) undistorted normalised coordinates of the rays in the device frame.
    - R_dev_world (3,3), t_dev_world (3,): the device pose (world -> device).
    - cell: normalised size of a binning cell (~1/focal length) for mesh queries.
    """

    origin: torch.Tensor
    dirs: torch.Tensor
    xy: torch.Tensor
    R_dev_world: torch.Tensor
    t_dev_world: torch.Tensor
    cell: float
    key: str = "camera"


@dataclass
class Hits:
    t: torch.Tensor        # (N,) distance along the unit ray (mm), inf where no hit
    normal: torch.Tensor   # (N,3) unit normal, world frame
    local: torch.Tensor    # (N,3) hit point in the object frame (mm)


class SceneObject:
    """Base class. ``convex`` objects cannot cast a shadow on themselves."""

    convex = False
    kind = "object"

    def __init__(self, name: str, R, t, albedo: float = 0.8):
        if not 0.0 <= float(albedo) <= 1.0:
            raise SynthError(f"{name}.albedo: expected within [0, 1], got {albedo!r}")
        self.name = name
        self.R = torch.tensor(np.asarray(R, dtype=np.float64))
        self.t = torch.tensor(np.asarray(t, dtype=np.float64))
        self.albedo_value = float(albedo)

    def _to_local(self, rays: Rays):
        o = (rays.origin - self.t) @ self.R  # R^T (o - t)
        d = rays.dirs @ self.R
        return o, d

    def albedo(self, local: torch.Tensor, footprint_mm: torch.Tensor) -> torch.Tensor:
        return torch.full(local.shape[:1], self.albedo_value, dtype=F64)

    def intersect(self, rays: Rays) -> Hits:  # pragma: no cover - abstract
        raise NotImplementedError

    def distance(self, rays: Rays) -> torch.Tensor:
        """(N,) distance along each unit ray to the nearest hit (inf: none), e.g. for shadow
        rays; objects override it when they can skip the normals and object-frame points."""
        return self.intersect(rays).t

    def describe(self) -> dict:
        return {"name": self.name, "kind": self.kind, "R": self.R.tolist(), "t": self.t.tolist()}


class Plane(SceneObject):
    """The plane z = 0 of the object frame; ``size_mm = (w, h)`` bounds it (centred), or None."""

    convex = True
    kind = "plane"

    def __init__(self, name, R, t, albedo=0.8, size_mm=None):
        super().__init__(name, R, t, albedo)
        if size_mm is not None:
            size_mm = tuple(float(v) for v in size_mm)
            if len(size_mm) != 2 or min(size_mm) <= 0:
                raise SynthError(f"{name}.size_mm: expected [width, height] > 0, got {size_mm!r}")
        self.size_mm = size_mm

    def intersect(self, rays: Rays) -> Hits:
        o, d = self._to_local(rays)
        dz = d[:, 2]
        ok = dz.abs() > 1e-12
        t = -o[2] / torch.where(ok, dz, torch.ones_like(dz))
        local = o + t[:, None] * d
        ok = ok & (t > 1e-9)
        if self.size_mm is not None:
            ok = ok & (local[:, 0].abs() <= self.size_mm[0] / 2) & (local[:, 1].abs() <= self.size_mm[1] / 2)
        t = torch.where(ok, t, torch.full_like(t, float("inf")))
        normal = self.R[:, 2].expand(t.shape[0], 3)
        return Hits(t, normal, local)

    def describe(self):
        return {**super().describe(), "size_mm": self.size_mm, "albedo": self.albedo_value}


class Board(Plane):
    """A printed calibration board (board frame of DESIGN.md) on a finite plane. ``spec``: a
    :class:`synth.scenes.boards.BoardTexture`, or a ``calib.board.Board`` printed with the default texture."""

    kind = "board"

    def __init__(self, name, R, t, spec):
        spec = spec if isinstance(spec, BoardTexture) else BoardTexture(spec)
        super().__init__(name, R, t, spec.albedo_light, spec.size_mm)
        self.spec = spec

    def albedo(self, local, footprint_mm):
        return self.spec.albedo(local[:, :2], footprint_mm)

    def describe(self):
        return {**super().describe(), "board": self.spec.board.to_dict()}


class Sphere(SceneObject):
    """A sphere of ``radius_mm`` centred at the pose translation."""

    convex = True
    kind = "sphere"

    def __init__(self, name, R, t, albedo=0.8, radius_mm=25.4):
        super().__init__(name, R, t, albedo)
        if not float(radius_mm) > 0:
            raise SynthError(f"{name}.radius_mm: expected > 0, got {radius_mm!r}")
        self.radius = float(radius_mm)

    def intersect(self, rays: Rays) -> Hits:
        oc = rays.origin - self.t
        d = rays.dirs
        b = d @ oc
        c = float(oc @ oc) - self.radius ** 2
        disc = b * b - c
        ok = disc >= 0
        sq = torch.sqrt(disc.clamp(min=0))
        # numerically stable roots of t^2 + 2 b t + c = 0
        q = -b - torch.where(b >= 0, sq, -sq)
        t1 = q
        t2 = c / torch.where(q != 0, q, torch.ones_like(q))
        lo, hi = torch.minimum(t1, t2), torch.maximum(t1, t2)
        t = torch.where(lo > 1e-9, lo, hi)
        ok = ok & (t > 1e-9)
        t = torch.where(ok, t, torch.full_like(t, float("inf")))
        p = rays.origin + torch.where(ok, t, torch.zeros_like(t))[:, None] * d
        normal = (p - self.t) / self.radius
        local = (p - self.t) @ self.R
        return Hits(t, normal, local)

    def describe(self):
        return {**super().describe(), "radius_mm": self.radius, "albedo": self.albedo_value}


class Mesh(SceneObject):
    """A triangle mesh (object-frame vertices in mm after scaling). Degenerate (zero-area)
    triangles are dropped at construction; ``smooth`` interpolates area-weighted vertex normals."""

    kind = "mesh"

    def __init__(self, name, R, t, vertices, faces, albedo=0.8, smooth=False, source=""):
        super().__init__(name, R, t, albedo)
        V = torch.tensor(np.asarray(vertices, dtype=np.float64))
        F = torch.tensor(np.asarray(faces, dtype=np.int64))
        tri = V[F]
        area = triangle_areas(tri)
        good = area > 1e-12 * max(float(area.max()) if area.numel() else 0.0, 1e-300)
        self.dropped_degenerate = int((~good).sum())
        if not bool(good.any()):
            raise SynthError(f"{name}: every triangle of the mesh is degenerate (zero area)")
        self.F = F[good]
        self.V = V
        self.tri = tri[good]
        n = torch.cross(self.tri[:, 1] - self.tri[:, 0], self.tri[:, 2] - self.tri[:, 0], dim=-1)
        self.face_normal = n / torch.linalg.norm(n, dim=-1, keepdim=True)
        self.smooth = bool(smooth)
        if self.smooth:
            vn = torch.zeros_like(V)
            vn.index_add_(0, self.F.reshape(-1), n.repeat_interleave(3, dim=0))
            self.vertex_normal = vn / torch.linalg.norm(vn, dim=-1, keepdim=True).clamp(min=1e-300)
        self.source = source
        self._cache: dict = {}

    @property
    def n_triangles(self) -> int:
        return int(self.tri.shape[0])

    def _tri_dev(self, rays: Rays) -> torch.Tensor:
        """The triangles in the rays' device frame (cached for the last pose of each device:
        the camera pass and the projector's shadow pass alternate)."""
        key = (rays.key, tuple(rays.R_dev_world.reshape(-1).tolist()), tuple(rays.t_dev_world.tolist()))
        tri_dev = self._cache.get(key)
        if tri_dev is None:
            R_dev_obj = rays.R_dev_world @ self.R
            t_dev_obj = rays.R_dev_world @ self.t + rays.t_dev_world
            tri_dev = self.tri @ R_dev_obj.T + t_dev_obj
            self._cache = {k: v for k, v in self._cache.items() if k[0] != rays.key}
            self._cache[key] = tri_dev
        return tri_dev

    def distance(self, rays: Rays) -> torch.Tensor:
        s, idx, _ = nearest_hits(self._tri_dev(rays), rays.xy, rays.cell)
        return torch.where(idx >= 0, s * torch.sqrt(1.0 + (rays.xy ** 2).sum(1)), torch.full_like(s, float("inf")))

    def intersect(self, rays: Rays) -> Hits:
        s, idx, bary = nearest_hits(self._tri_dev(rays), rays.xy, rays.cell)
        if rays.xy.device.type == "cpu" and numba_engine_available():
            return self._hits_numba(rays, s, idx, bary)
        hit = idx >= 0
        ray_len = torch.sqrt(1.0 + (rays.xy ** 2).sum(1))
        t = torch.where(hit, s * ray_len, torch.full_like(s, float("inf")))
        safe = idx.clamp(min=0)
        if self.smooth:
            vn = self.vertex_normal[self.F[safe]]
            n_obj = (1 - bary.sum(1, keepdim=True)) * vn[:, 0] + bary[:, :1] * vn[:, 1] + bary[:, 1:] * vn[:, 2]
            n_obj = n_obj / torch.linalg.norm(n_obj, dim=1, keepdim=True).clamp(min=1e-300)
        else:
            n_obj = self.face_normal[safe]
        o, d = self._to_local(rays)
        local = o + torch.where(hit, t, torch.zeros_like(t))[:, None] * d
        return Hits(t, n_obj @ self.R.T, local)

    def _hits_numba(self, rays: Rays, s, idx, bary) -> Hits:
        """The torch post-processing below in one fused pass (CPU tensors)."""
        from ..renderer._raycast_kernel import mesh_hits

        N = s.shape[0]
        t = torch.empty(N, dtype=F64)
        n_world = torch.empty((N, 3), dtype=F64)
        local = torch.empty((N, 3), dtype=F64)
        o_local = (rays.origin - self.t) @ self.R
        normals = self.vertex_normal if self.smooth else self.face_normal
        c = lambda x: x.detach().contiguous().numpy()  # noqa: E731
        mesh_hits(c(s), c(idx), c(bary), c(rays.xy), c(rays.dirs), c(o_local), c(self.R), c(self.F),
                  c(normals), self.smooth, t.numpy(), n_world.numpy(), local.numpy())
        return Hits(t, n_world, local)

    def describe(self):
        return {**super().describe(), "triangles": self.n_triangles, "dropped_degenerate": self.dropped_degenerate,
                "source": self.source, "albedo": self.albedo_value}
