"""Nearest ray-triangle hits for rays that share one origin (a camera or projector centre).

Brute force is rays x triangles (3e10 for 640x480 and 100k triangles); instead each triangle is
projected (pinhole, no distortion) into the device's normalised image plane, where its edges
stay straight, and tested only against the rays whose normalised coordinates fall in cells of
its bounding box. The exact Moeller-Trumbore test then decides, in float64.

Two engines, one contract: tensors on the CPU go to the numba engine ``synth.renderer._raycast_kernel``
(triangle-major within bands of grid rows, the bands in parallel; when numba is installed),
others (GPU) to the torch engine below (pair-centric). Both use the same binning and the same
float64 Moeller-Trumbore operations and thresholds; they agree on depth to 1e-12 relative and on
the triangle index except at exact ties (a ray through a shared edge), where the numba engine
takes the lower index and the torch engine either (tests/test_synth_raycast.py).

Memory is bounded whatever the mesh size: the torch engine processes triangles in chunks holding
at most ``max_pairs`` (triangle, ray) candidate pairs (default 2**19; about 150 MB of
temporaries); the numba engine stores no pairs at all (~56 bytes a ray, 16 a grid cell, ~120 a
triangle; see its module).

Frames: the triangles are given in the device frame (mm), rays are ``(x, y, 1)`` with ``(x, y)``
undistorted normalised coordinates; the returned ``s`` is the device-frame depth ``z`` of the hit
(distance along the unit ray is ``s * |(x, y, 1)|``).
"""
from __future__ import annotations

import torch

from ..errors import SynthError

NEAR_Z = 1e-9  # mm; vertices closer to the device plane count as "behind"


def triangle_areas(tri: torch.Tensor) -> torch.Tensor:
    """(T,3,3) vertices -> (T,) triangle areas (units^2)."""
    return 0.5 * torch.linalg.norm(torch.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], dim=-1), dim=-1)


def numba_engine_available() -> bool:
    """True when numba is importable (the CPU engine can run)."""
    try:
        from . import _raycast_kernel  # noqa: F401
    except ImportError:
        return False
    return True


def nearest_hits(tri_dev: torch.Tensor, xy: torch.Tensor, cell: float, *,
                 max_pairs: int = 1 << 19,
                 engine: str = "auto") -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Nearest hit of each ray ``(x, y, 1)`` among triangles ``tri_dev``.

    ARGUMENTS
    - tri_dev: (T,3,3) float64 triangle vertices in the device frame (mm).
    - xy: (N,2) float64 normalised ray coordinates (non-finite rows never hit).
    - cell: binning cell size in normalised units (about one pixel: 1/focal length).
    - max_pairs: torch engine: bound on candidate pairs held at once (memory bound).
    - engine: "auto" (numba for CPU tensors when installed, else torch), "numba" or "torch".

    RETURNED VALUE: ``(s, tri_index, bary)``: depth (N,) (inf where no hit), triangle index (N,)
    int64 (-1 where no hit), barycentric ``(b1, b2)`` (N,2) of the hit (weights of vertices 1, 2).
    """
    if engine not in ("auto", "numba", "torch"):
        raise SynthError(f"nearest_hits: engine must be 'auto', 'numba' or 'torch', got {engine!r}")
    on_cpu = xy.device.type == "cpu" and tri_dev.device.type == "cpu"
    if engine == "numba" or (engine == "auto" and on_cpu and numba_engine_available()):
        if not on_cpu:
            raise SynthError("nearest_hits: the numba engine needs CPU tensors")
        from ._raycast_kernel import nearest_hits_numba
        s, idx, bary = nearest_hits_numba(
            tri_dev.detach().to(torch.float64).contiguous().numpy(),
            xy.detach().to(torch.float64).contiguous().numpy(), float(cell), NEAR_Z)
        return torch.from_numpy(s), torch.from_numpy(idx), torch.from_numpy(bary)
    return _nearest_hits_torch(tri_dev, xy, cell, max_pairs)


def _nearest_hits_torch(tri_dev, xy, cell, max_pairs):
    """The torch engine of :func:`nearest_hits` (any device)."""
    dev = xy.device
    N = xy.shape[0]
    s_best = torch.full((N,), float("inf"), dtype=torch.float64, device=dev)
    tri_best = torch.full((N,), -1, dtype=torch.int64, device=dev)
    finite = torch.isfinite(xy).all(dim=1)
    if tri_dev.shape[0] == 0 or not bool(finite.any()):
        return s_best, tri_best, torch.zeros((N, 2), dtype=torch.float64, device=dev)
    ray_ids = torch.nonzero(finite).squeeze(1)
    g = torch.floor(xy[ray_ids] / cell).to(torch.int64)
    gx0, gy0 = int(g[:, 0].min()), int(g[:, 1].min())
    nx, ny = int(g[:, 0].max()) - gx0 + 1, int(g[:, 1].max()) - gy0 + 1
    cid = (g[:, 1] - gy0) * nx + (g[:, 0] - gx0)
    order = torch.argsort(cid)
    rays_sorted = ray_ids[order]
    counts = torch.bincount(cid, minlength=nx * ny)
    starts = torch.cumsum(counts, 0) - counts

    # triangle bounding boxes in cells; triangles wholly behind the device are dropped, those
    # crossing the device plane get the whole grid (their projection is unbounded)
    z = tri_dev[:, :, 2]
    behind = z <= NEAR_Z
    all_behind = behind.all(dim=1)
    some_behind = behind.any(dim=1) & ~all_behind
    zs = torch.where(behind, torch.ones_like(z), z)
    p = tri_dev[:, :, :2] / zs[..., None]
    lo = torch.floor(p.amin(dim=1) / cell).to(torch.int64)
    hi = torch.floor(p.amax(dim=1) / cell).to(torch.int64)
    bx0 = (lo[:, 0] - gx0).clamp(0, nx - 1)
    by0 = (lo[:, 1] - gy0).clamp(0, ny - 1)
    bx1 = (hi[:, 0] - gx0).clamp(0, nx - 1)
    by1 = (hi[:, 1] - gy0).clamp(0, ny - 1)
    outside = (hi[:, 0] < gx0) | (hi[:, 1] < gy0) | (lo[:, 0] >= gx0 + nx) | (lo[:, 1] >= gy0 + ny)
    bx0 = torch.where(some_behind, torch.zeros_like(bx0), bx0)
    by0 = torch.where(some_behind, torch.zeros_like(by0), by0)
    bx1 = torch.where(some_behind, torch.full_like(bx1, nx - 1), bx1)
    by1 = torch.where(some_behind, torch.full_like(by1, ny - 1), by1)
    keep = ~all_behind & (some_behind | ~outside)
    tids = torch.nonzero(keep).squeeze(1)
    if tids.numel() == 0:
        return s_best, tri_best, torch.zeros((N, 2), dtype=torch.float64, device=dev)
    bx0, by0, bx1, by1 = bx0[tids], by0[tids], bx1[tids], by1[tids]
    w = bx1 - bx0 + 1
    ncell = w * (by1 - by0 + 1)
    # rays per triangle: summed per-cell counts over the box (2-D prefix sums)
    csum = torch.zeros((ny + 1, nx + 1), dtype=torch.int64, device=dev)
    csum[1:, 1:] = counts.view(ny, nx).cumsum(0).cumsum(1)
    npairs = csum[by1 + 1, bx1 + 1] - csum[by0, bx1 + 1] - csum[by1 + 1, bx0] + csum[by0, bx0]
    work = torch.maximum(npairs, ncell)
    cum = torch.cumsum(work, 0)
    start = 0
    T = tids.numel()
    while start < T:
        # largest chunk whose work fits in max_pairs (at least one triangle)
        base = int(cum[start - 1]) if start > 0 else 0
        end = int(torch.searchsorted(cum, torch.tensor(base + max_pairs, device=dev), right=True))
        end = max(end, start + 1)
        _chunk(tri_dev, xy, tids[start:end], bx0[start:end], by0[start:end], w[start:end],
               ncell[start:end], nx, counts, starts, rays_sorted, s_best, tri_best)
        start = end
    hit = tri_best >= 0
    bary = torch.zeros((N, 2), dtype=torch.float64, device=dev)
    if bool(hit.any()):
        r = torch.nonzero(hit).squeeze(1)
        _, b1, b2, _ = _moller_trumbore(tri_dev[tri_best[r]], xy[r])
        bary[r, 0], bary[r, 1] = b1, b2
    return s_best, tri_best, bary


def _moller_trumbore(tri: torch.Tensor, xy: torch.Tensor):
    """Rays from the origin along (x, y, 1) against triangles (P,3,3): (s, b1, b2, ok)."""
    d = torch.cat([xy, torch.ones_like(xy[:, :1])], dim=1)
    v0 = tri[:, 0]
    e1 = tri[:, 1] - v0
    e2 = tri[:, 2] - v0
    pvec = torch.cross(d, e2, dim=1)
    det = (e1 * pvec).sum(1)
    # relative determinant threshold: rays (nearly) in the triangle's plane and degenerate
    # (zero-area) triangles never hit
    scale = torch.linalg.norm(e1, dim=1) * torch.linalg.norm(e2, dim=1) * torch.linalg.norm(d, dim=1)
    ok = det.abs() > 1e-12 * scale
    inv = 1.0 / torch.where(ok, det, torch.ones_like(det))
    tvec = -v0
    b1 = (tvec * pvec).sum(1) * inv
    qvec = torch.cross(tvec, e1, dim=1)
    b2 = (d * qvec).sum(1) * inv
    s = (e2 * qvec).sum(1) * inv
    eps = 1e-12
    ok = ok & (b1 >= -eps) & (b2 >= -eps) & (b1 + b2 <= 1 + eps) & (s > NEAR_Z)
    return s, b1, b2, ok


def _chunk(tri_dev, xy, tids, bx0, by0, w, ncell, nx, counts, starts, rays_sorted, s_best, tri_best):
    dev = xy.device
    # (triangle, cell) pairs
    pt = torch.repeat_interleave(torch.arange(tids.numel(), device=dev), ncell)
    off = torch.cumsum(ncell, 0) - ncell
    local = torch.arange(pt.numel(), device=dev) - off[pt]
    cx = bx0[pt] + local % w[pt]
    cy = by0[pt] + torch.div(local, w[pt], rounding_mode="floor")
    cell_id = cy * nx + cx
    cnt = counts[cell_id]
    nz = cnt > 0
    pt, cell_id, cnt = pt[nz], cell_id[nz], cnt[nz]
    if pt.numel() == 0:
        return
    # (triangle, ray) pairs
    pr_t = torch.repeat_interleave(pt, cnt)
    off2 = torch.cumsum(cnt, 0) - cnt
    local2 = torch.arange(pr_t.numel(), device=dev) - torch.repeat_interleave(off2, cnt)
    ray = rays_sorted[torch.repeat_interleave(starts[cell_id], cnt) + local2]
    tri_global = tids[pr_t]
    s, _, _, ok = _moller_trumbore(tri_dev[tri_global], xy[ray])
    if not bool(ok.any()):
        return
    s, ray, tri_global = s[ok], ray[ok], tri_global[ok]
    chunk_best = torch.full_like(s_best, float("inf"))
    chunk_best.scatter_reduce_(0, ray, s, reduce="amin")
    win = s == chunk_best[ray]
    better = chunk_best < s_best
    r_w, t_w = ray[win], tri_global[win]
    upd = better[r_w]
    tri_best[r_w[upd]] = t_w[upd]
    s_best.copy_(torch.minimum(s_best, chunk_best))
