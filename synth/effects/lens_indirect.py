"""The thin lens's indirect light computed once per scene: the lens centre's interreflection
looked up at the surface points every aperture point sees.

A Lambertian surface point's indirect radiance does not depend on where the camera looks from,
so the camera's aperture points only change *which* surface point a pixel sees. The projector's
aperture points move the emitters' illumination a little; the interreflection's patches already
integrate the pattern with the projector's defocus sigma (synth.effects.interreflection,
:func:`~synth.effects.interreflection.patch_values`), so the lens centre's transport, with the
projector's blur, is the shared estimate of all of them.

:class:`SharedIndirect` computes, once, the indirect light per unit albedo at every surface
point the lens centre sees (the Transport's receivers: the centre's hit pixels; rows: the linear
patterns' basis rows, then the nonlinear patterns). For one aperture point, each hit point X
(camera frame, mm) is projected into the centre camera and bilinearly interpolated from the four
centre pixels around it, a neighbour counting only where it sees the *same surface*: the same
object, within ``tol`` = 3 pixel footprints (depth / f, divided by the cosine between the view
ray and the normal, at least 0.15) of X, with normals within 37 degrees (cosine >= 0.8); the
weights are renormalised over those neighbours. A point whose same-surface neighbours hold less
than half of the weight (the wall disoccluded behind an outline, seen only from part of the
aperture; a surface outside the centre's image) is computed exactly: the centre's Transport
(same patches) with that point as receiver. The indirect light is then the point's own albedo
times the looked-up value (times its pixel's vignetting, as in the exact path).

Frames: receivers in the world frame for the Transport, points in the (centre) camera frame for
the look-up; shapes: rows Q, centre receivers M0, one aperture point's hit pixels M.
"""
from __future__ import annotations

import numpy as np
import torch

from .interreflection import Transport, patch_values

F64 = torch.float64
#: a same-surface neighbour lies within this many pixel footprints (over the view cosine)
TOL_FOOTPRINTS = 3.0
#: and its normal within this cosine of the point's
MIN_NORMAL_COS = 0.8
#: below this interpolation weight on same-surface neighbours a point is computed exactly
MIN_WEIGHT = 0.5


class SharedIndirect:
    """The lens centre's indirect light, shared by the aperture points of one thin-lens render.

    ``scene``: the scene with its defocus as a blur (synth.effects.thin_lens.without_sampling; its
    projector's defocus sigma widens the patches' pattern integral); ``centre``: the lens centre's
    Geometry. :meth:`rows` is what synth.effects.interreflection.apply_interreflection calls for
    an aperture point's geometry carrying this object as ``shared_indirect``."""

    def __init__(self, scene, centre):
        from ..renderer.projection import linear_model

        eff, cam = scene.effects, scene.system.camera
        self.size = centre.size
        hit = torch.nonzero(centre.hit).squeeze(1)
        Rc, tc = torch.tensor(cam.R), torch.tensor(cam.t)
        self.P0 = centre.points_cam[hit]
        self.n0 = centre.normals_cam[hit]
        self.obj0 = centre.object_id[hit]
        self.row_of = torch.full((centre.hit.numel(),), -1, dtype=torch.int64)
        self.row_of[hit] = torch.arange(hit.numel())
        ones = torch.ones(hit.numel(), dtype=F64)
        self.T = Transport(scene, (self.P0 - tc) @ Rc, self.n0 @ Rc, ones, self.obj0, eff.interreflection)
        prj = scene.system.projector
        idx, _, _ = linear_model(scene.patterns, self.T.fine.uv[:1, 0], self.T.fine.uv[:1, 1], prj.size, eff, None)
        other = [k for k in range(len(scene.patterns)) if k not in set(idx)]
        self.values, self.R = patch_values(scene, self.T.fine, other)
        self.E0 = self.T.apply(self.values)                  # (Q, M0) per unit albedo, unvignetted
        self.Rc, self.tc = Rc, tc
        use_dist = eff.camera_distortion and bool(np.any(cam.distortion))
        self.cam = cam if use_dist else cam.with_(distortion=np.zeros(0))
        self.f = float(max(cam.fx, cam.fy))
        self.counts = {"points": 0, "looked up": 0, "exact": 0}

    def neighbours(self, P, n, obj):
        """Bilinear look-up of camera-frame points ``P`` (M,3) with normals ``n`` (M,3) on objects
        ``obj`` (M,): (rows (M,4) of the centre receivers, -1 where none; weights (M,4), 0 where
        not the same surface)."""
        W, H = self.size
        q = torch.from_numpy(self.cam.project_device(P.numpy()))
        q = torch.nan_to_num(q, nan=-10.0)
        base = torch.floor(q)
        fr = q - base
        b = base.to(torch.int64)
        view = P / torch.linalg.norm(P, dim=1, keepdim=True)
        cos_v = (n * view).sum(1).abs().clamp(min=0.15)
        tol = TOL_FOOTPRINTS * P[:, 2] / self.f / cos_v
        rows = torch.full((P.shape[0], 4), -1, dtype=torch.int64)
        w = torch.zeros((P.shape[0], 4), dtype=F64)
        for k, (dx, dy) in enumerate(((0, 0), (1, 0), (0, 1), (1, 1))):
            u, v = b[:, 0] + dx, b[:, 1] + dy
            inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
            r = torch.where(inside, self.row_of[(v.clamp(0, H - 1) * W + u.clamp(0, W - 1))], -1)
            ok = r >= 0
            rc = r.clamp(min=0)
            ok &= self.obj0[rc] == obj
            ok &= torch.linalg.norm(self.P0[rc] - P, dim=1) <= tol
            ok &= (self.n0[rc] * n).sum(1) >= MIN_NORMAL_COS
            wk = (fr[:, 0] if dx else 1 - fr[:, 0]) * (fr[:, 1] if dy else 1 - fr[:, 1])
            rows[:, k] = torch.where(ok, r, -1)
            w[:, k] = torch.where(ok, wk, torch.zeros_like(wk))
        return rows, w

    def rows(self, geometry, hit):
        """The indirect light (Q, M) at the hit pixels ``hit`` of an aperture point's
        ``geometry`` (its albedo applied, not its vignetting), R (the number of basis rows) and
        the stats of the exact part."""
        P = geometry.points_cam[hit]
        n = geometry.normals_cam[hit]
        rows, w = self.neighbours(P, n, geometry.object_id[hit])
        ws = w.sum(1)
        good = ws >= MIN_WEIGHT
        out = torch.zeros((self.E0.shape[0], hit.numel()), dtype=F64)
        gi = torch.nonzero(good).squeeze(1)
        wn = w[gi] / ws[gi, None]
        for k in range(4):
            out[:, gi] += self.E0[:, rows[gi, k].clamp(min=0)] * wn[:, k]
        bad = torch.nonzero(~good).squeeze(1)
        stats = {"looked up": int(gi.numel()), "exact": int(bad.numel())}
        if bad.numel():
            T = self.T.towards((P[bad] - self.tc) @ self.Rc, n[bad] @ self.Rc, torch.ones(bad.numel(), dtype=F64),
                               geometry.object_id[hit][bad])
            out[:, bad] = T.apply(self.values)
            stats.update(T.stats)
        self.counts["points"] += hit.numel()
        self.counts["looked up"] += stats["looked up"]
        self.counts["exact"] += stats["exact"]
        return out * geometry.albedo[hit], self.R, stats

    def describe(self) -> str:
        """The plan line of the shared indirect light (counts so far)."""
        c = self.counts
        return (f"shared across the aperture points (the lens centre's {self.E0.shape[1]} receivers, "
                f"{self.T.stats['fine patches']} fine / {self.T.stats['coarse patches']} coarse patches, "
                f"{self.T.ir.bounces} bounce(s)); {c['exact']} of {c['points']} aperture hit(s) computed exactly "
                f"(not seen by the centre), the rest looked up")
