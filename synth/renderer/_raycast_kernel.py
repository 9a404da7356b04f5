"""numba engine of :func:`synth.renderer.raycast.nearest_hits` for CPU tensors (imported only when numba is
installed).

The same algorithm and contract as the torch engine (see ``synth.renderer.raycast``): rays ``(x, y, 1)``
leave the device centre; each triangle is projected into the normalised image plane and binned
by the cells of its bounding box (a triangle with a vertex on or behind the plane ``z = NEAR_Z``
gets the whole grid, one wholly behind is dropped); the exact float64 Moeller-Trumbore test, with
the torch engine's operations and thresholds, decides. Triangle-major within bands of grid
rows, the bands in parallel (``prange``): each band walks, in index order, the triangles whose
box meets it and tests them against the rays of the box's cells in the band; a ray lies in
exactly one band, so each thread owns the nearest-hit records it updates and no (triangle, ray)
pair is ever stored. Ties (the same depth on two triangles, e.g. a shared edge) go to the lower
triangle index (met first).

Memory, whatever the mesh size: ~56 bytes a ray (outputs, sort, ray length), 16 bytes a grid cell
(the grid spans the rays' extent in cells, at most ``max(4 N, 2**20)`` cells: rays spread wider
get coarser cells), ~120 bytes a triangle (edges 80, box 32, band lists 8; a triangle whose box spans k
bands is listed k times). Work: a triangle crossing the device plane is tested against every
ray, as in the torch engine.

Measured (bench mesh, 1 thread, shared machine): 10-22 ns per (triangle, ray) candidate pair.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

_JIT = dict(cache=True, error_model="numpy", nogil=True)


@nb.njit(**_JIT)
def _sort_rays(xy, cell, gx0, gy0, nx, ny):
    """Counting sort of the finite rays by grid cell: (cell_start (nx*ny+1,), rays_sorted)."""
    n_cells = nx * ny
    counts = np.zeros(n_cells + 1, dtype=np.int64)
    cid = np.full(xy.shape[0], -1, dtype=np.int64)
    for i in range(xy.shape[0]):
        x = xy[i, 0]
        y = xy[i, 1]
        if math.isfinite(x) and math.isfinite(y):
            c = (int(math.floor(y / cell)) - gy0) * nx + (int(math.floor(x / cell)) - gx0)
            cid[i] = c
            counts[c + 1] += 1
    for c in range(n_cells):
        counts[c + 1] += counts[c]
    fill = counts[:-1].copy()
    rays_sorted = np.empty(counts[n_cells], dtype=np.int64)
    for i in range(xy.shape[0]):
        c = cid[i]
        if c >= 0:
            rays_sorted[fill[c]] = i
            fill[c] += 1
    return counts, rays_sorted


_BIG = float(1 << 60)  # cell indices are clamped here before the integer conversion (no overflow)


@nb.njit(inline="always", **_JIT)
def _cell_of(v, cell):
    return int(math.floor(min(max(v / cell, -_BIG), _BIG)))


@nb.njit(**_JIT)
def _triangle_boxes(tri, cell, gx0, gy0, nx, ny, near_z):
    """Cell boxes (T,4) [bx0, by0, bx1, by1] of the triangles, bx0 = -1 for a dropped triangle."""
    T = tri.shape[0]
    box = np.empty((T, 4), dtype=np.int64)
    for t in range(T):
        n_behind = 0
        finite = True
        for k in range(3):
            if tri[t, k, 2] <= near_z:
                n_behind += 1
            for j in range(3):
                finite = finite and math.isfinite(tri[t, k, j])
        if n_behind == 3 or not finite:  # wholly behind, or not a triangle: never hit
            box[t, 0] = -1
            continue
        if n_behind > 0:  # crosses the device plane: its projection is unbounded
            box[t, 0] = 0
            box[t, 1] = 0
            box[t, 2] = nx - 1
            box[t, 3] = ny - 1
            continue
        px0 = tri[t, 0, 0] / tri[t, 0, 2]
        py0 = tri[t, 0, 1] / tri[t, 0, 2]
        xmin = px0
        xmax = px0
        ymin = py0
        ymax = py0
        for k in range(1, 3):
            px = tri[t, k, 0] / tri[t, k, 2]
            py = tri[t, k, 1] / tri[t, k, 2]
            xmin = min(xmin, px)
            xmax = max(xmax, px)
            ymin = min(ymin, py)
            ymax = max(ymax, py)
        lx = _cell_of(xmin, cell) - gx0
        ly = _cell_of(ymin, cell) - gy0
        hx = _cell_of(xmax, cell) - gx0
        hy = _cell_of(ymax, cell) - gy0
        if hx < 0 or hy < 0 or lx >= nx or ly >= ny:
            box[t, 0] = -1
            continue
        box[t, 0] = max(lx, 0)
        box[t, 1] = max(ly, 0)
        box[t, 2] = min(hx, nx - 1)
        box[t, 3] = min(hy, ny - 1)
    return box


@nb.njit(parallel=True, **_JIT)
def _edges(tri):
    """Per triangle (T,10): v0, e1 = v1 - v0, e2 = v2 - v0, |e1| |e2| (computed once, not per pair)."""
    pre = np.empty((tri.shape[0], 10))
    for t in nb.prange(tri.shape[0]):
        v0x = tri[t, 0, 0]
        v0y = tri[t, 0, 1]
        v0z = tri[t, 0, 2]
        e1x = tri[t, 1, 0] - v0x
        e1y = tri[t, 1, 1] - v0y
        e1z = tri[t, 1, 2] - v0z
        e2x = tri[t, 2, 0] - v0x
        e2y = tri[t, 2, 1] - v0y
        e2z = tri[t, 2, 2] - v0z
        pre[t, 0] = v0x
        pre[t, 1] = v0y
        pre[t, 2] = v0z
        pre[t, 3] = e1x
        pre[t, 4] = e1y
        pre[t, 5] = e1z
        pre[t, 6] = e2x
        pre[t, 7] = e2y
        pre[t, 8] = e2z
        pre[t, 9] = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z) * math.sqrt(e2x * e2x + e2y * e2y + e2z * e2z)
    return pre


@nb.njit(**_JIT)
def _band_lists(box, ny, rows_per_band, n_bands):
    """Per band of grid rows, the triangles whose cell box meets it, in index order (CSR)."""
    start = np.zeros(n_bands + 1, dtype=np.int64)
    for t in range(box.shape[0]):
        if box[t, 0] >= 0:
            for b in range(box[t, 1] // rows_per_band, box[t, 3] // rows_per_band + 1):
                start[b + 1] += 1
    for b in range(n_bands):
        start[b + 1] += start[b]
    fill = start[:-1].copy()
    tris = np.empty(start[n_bands], dtype=np.int64)
    for t in range(box.shape[0]):
        if box[t, 0] >= 0:
            for b in range(box[t, 1] // rows_per_band, box[t, 3] // rows_per_band + 1):
                tris[fill[b]] = t
                fill[b] += 1
    return start, tris


@nb.njit(parallel=True, **_JIT)
def _trace_bands(pre, xy, dn, box, band_start, band_tris, rows_per_band, ray_start, rays_sorted, nx, ny,
                 near_z, s_best, tri_best, bary):
    """Triangle-major within each band of grid rows, bands in parallel (a ray lies in one band, so
    no two threads update the same ray): every triangle of the band against the rays of the
    cells of its box; each ray keeps its nearest hit (ties: the lower index, met first)."""
    for band in nb.prange(band_start.shape[0] - 1):
        y0 = band * rows_per_band
        y1 = min(y0 + rows_per_band, ny) - 1
        for m in range(band_start[band], band_start[band + 1]):
            t = band_tris[m]
            v0x = pre[t, 0]
            v0y = pre[t, 1]
            v0z = pre[t, 2]
            e1x = pre[t, 3]
            e1y = pre[t, 4]
            e1z = pre[t, 5]
            e2x = pre[t, 6]
            e2y = pre[t, 7]
            e2z = pre[t, 8]
            n12 = pre[t, 9]
            tx = -v0x
            ty = -v0y
            tz = -v0z
            # qvec = tvec x e1 (independent of the ray)
            qx = ty * e1z - tz * e1y
            qy = tz * e1x - tx * e1z
            qz = tx * e1y - ty * e1x
            for cy in range(max(box[t, 1], y0), min(box[t, 3], y1) + 1):
                for c in range(cy * nx + box[t, 0], cy * nx + box[t, 2] + 1):
                    for k in range(ray_start[c], ray_start[c + 1]):
                        r = rays_sorted[k]
                        dx = xy[r, 0]
                        dy = xy[r, 1]
                        # pvec = d x e2, d = (dx, dy, 1)
                        px = dy * e2z - e2y
                        py = e2x - dx * e2z
                        pz = dx * e2y - dy * e2x
                        det = e1x * px + e1y * py + e1z * pz
                        if not abs(det) > 1e-12 * (n12 * dn[r]):  # in the triangle's plane, or degenerate
                            continue
                        inv = 1.0 / det
                        b1 = (tx * px + ty * py + tz * pz) * inv
                        b2 = (dx * qx + dy * qy + qz) * inv
                        s = (e2x * qx + e2y * qy + e2z * qz) * inv
                        if (b1 >= -1e-12 and b2 >= -1e-12 and b1 + b2 <= 1.0 + 1e-12 and s > near_z
                                and s < s_best[r]):
                            s_best[r] = s
                            tri_best[r] = t
                            bary[r, 0] = b1
                            bary[r, 1] = b2


@nb.njit(**_JIT)
def _max_abs(xy):
    """(number of finite rays, largest |x| or |y| among them)."""
    n = 0
    m = 0.0
    for i in range(xy.shape[0]):
        x = xy[i, 0]
        y = xy[i, 1]
        if math.isfinite(x) and math.isfinite(y):
            n += 1
            m = max(m, abs(x), abs(y))
    return n, m


@nb.njit(**_JIT)
def _extent(xy, cell):
    """(n_finite, gx0, gy0, gx1, gy1): the finite rays' range of cells."""
    n = 0
    gx0 = gy0 = np.iinfo(np.int64).max
    gx1 = gy1 = np.iinfo(np.int64).min
    for i in range(xy.shape[0]):
        x = xy[i, 0]
        y = xy[i, 1]
        if math.isfinite(x) and math.isfinite(y):
            n += 1
            gx = int(math.floor(x / cell))
            gy = int(math.floor(y / cell))
            gx0 = min(gx0, gx)
            gx1 = max(gx1, gx)
            gy0 = min(gy0, gy)
            gy1 = max(gy1, gy)
    return n, gx0, gy0, gx1, gy1


@nb.njit(parallel=True, **_JIT)
def _init_rays(xy, dn, s_best, tri_best, bary):
    """Ray lengths ``|(x, y, 1)|`` and empty nearest-hit records."""
    for i in nb.prange(xy.shape[0]):
        dn[i] = math.sqrt(xy[i, 0] * xy[i, 0] + xy[i, 1] * xy[i, 1] + 1.0)
        s_best[i] = math.inf
        tri_best[i] = -1
        bary[i, 0] = 0.0
        bary[i, 1] = 0.0


def nearest_hits_numba(tri: np.ndarray, xy: np.ndarray, cell: float, near_z: float):
    """numpy twin of ``synth.renderer.raycast.nearest_hits``: (s (N,), tri_index (N,), bary (N,2))."""
    N = xy.shape[0]
    s_best = np.empty(N)
    tri_best = np.empty(N, dtype=np.int64)
    bary = np.empty((N, 2))
    dn = np.empty(N)
    _init_rays(xy, dn, s_best, tri_best, bary)
    n_finite, max_abs = _max_abs(xy)
    if tri.shape[0] == 0 or n_finite == 0:
        return s_best, tri_best, bary
    cell = max(cell, max_abs / 2.0 ** 52)  # ray cell indices stay exact integers (binning stays exact)
    n_finite, gx0, gy0, gx1, gy1 = _extent(xy, cell)
    nx, ny = gx1 - gx0 + 1, gy1 - gy0 + 1
    grid_limit = max(4 * N, 1 << 20)
    if nx * ny > grid_limit:  # rays spread far apart: coarser cells bound the grid (binning stays exact)
        cell *= math.ceil(math.sqrt(nx * ny / grid_limit))
        n_finite, gx0, gy0, gx1, gy1 = _extent(xy, cell)
        nx, ny = gx1 - gx0 + 1, gy1 - gy0 + 1
    ray_start, rays_sorted = _sort_rays(xy, cell, gx0, gy0, nx, ny)
    box = _triangle_boxes(tri, cell, gx0, gy0, nx, ny, near_z)
    pre = _edges(tri)
    n_bands = min(ny, 64)
    rows_per_band = -(-ny // n_bands)
    n_bands = -(-ny // rows_per_band)
    band_start, band_tris = _band_lists(box, ny, rows_per_band, n_bands)
    _trace_bands(pre, xy, dn, box, band_start, band_tris, rows_per_band, ray_start, rays_sorted, nx, ny,
                 near_z, s_best, tri_best, bary)
    return s_best, tri_best, bary


@nb.njit(parallel=True, **_JIT)
def mesh_hits(s, idx, bary, xy, dirs, o_local, R, F, normals, smooth, t_out, n_world, local):
    """Per ray, from the engine's (s, idx, bary): distance along the unit ray ``t`` (inf where no
    hit), the world normal (smooth: barycentric blend of the vertex ``normals`` of ``F``,
    normalised; else the face ``normals``) and the object-frame hit point ``o + t d`` (``o`` when
    no hit). ``R``: object -> world rotation; ``dirs``: unit world directions; ``o_local``: the
    ray origin in the object frame. The torch code's operations, fused (Mesh.intersect)."""
    for i in nb.prange(s.shape[0]):
        k = idx[i]
        hit = k >= 0
        tt = math.inf
        if hit:
            tt = s[i] * math.sqrt(1.0 + (xy[i, 0] * xy[i, 0] + xy[i, 1] * xy[i, 1]))
        kk = k if hit else 0
        if smooth:
            b1 = bary[i, 0]
            b2 = bary[i, 1]
            b0 = 1.0 - (b1 + b2)
            a = F[kk, 0]
            b = F[kk, 1]
            c = F[kk, 2]
            nx = b0 * normals[a, 0] + b1 * normals[b, 0] + b2 * normals[c, 0]
            ny = b0 * normals[a, 1] + b1 * normals[b, 1] + b2 * normals[c, 1]
            nz = b0 * normals[a, 2] + b1 * normals[b, 2] + b2 * normals[c, 2]
            nn = max(math.sqrt(nx * nx + ny * ny + nz * nz), 1e-300)
            nx /= nn
            ny /= nn
            nz /= nn
        else:
            nx = normals[kk, 0]
            ny = normals[kk, 1]
            nz = normals[kk, 2]
        t_out[i] = tt
        for j in range(3):
            n_world[i, j] = R[j, 0] * nx + R[j, 1] * ny + R[j, 2] * nz
        tl = tt if hit else 0.0
        for j in range(3):  # d_local = R^T d
            dl = R[0, j] * dirs[i, 0] + R[1, j] * dirs[i, 1] + R[2, j] * dirs[i, 2]
            local[i, j] = o_local[j] + tl * dl
