"""Segment-triangle occlusion for many segments with arbitrary end points (numba): a uniform grid
over the occluder triangles, each segment walked cell by cell (3-D DDA, Amanatides & Woo 1987)
with the Moeller-Trumbore test on the triangles binned in each cell, stopping at the first hit.

Used by synth.effects.interreflection for the visibility of patch pairs against meshes. Frames: world
mm. ``decimate`` builds a coarser occluder by vertex clustering when a mesh is large.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange


def decimate(V: np.ndarray, F: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertex clustering: vertices in the same ``cell`` (mm) cube merge into their mean; triangles
    that collapse are dropped, duplicates kept once. (V', F')."""
    q = np.floor((V - V.min(0)) / cell).astype(np.int64)
    _, label, inv_count = np.unique(q, axis=0, return_inverse=True, return_counts=True)
    label = label.reshape(-1)
    n = inv_count.size
    Vc = np.zeros((n, 3))
    np.add.at(Vc, label, V)
    Vc /= inv_count[:, None]
    Fc = label[F]
    keep = (Fc[:, 0] != Fc[:, 1]) & (Fc[:, 1] != Fc[:, 2]) & (Fc[:, 0] != Fc[:, 2])
    Fc = Fc[keep]
    Fc = np.unique(np.sort(Fc, axis=1), axis=0)
    return Vc, Fc


class SegmentGrid:
    """Triangles (T,3,3) binned in a uniform grid of cells ``cell_factor`` mean triangle extents
    wide (at most 256 a side)."""

    def __init__(self, tri: np.ndarray, cell_factor: float = 1.0):
        tri = np.ascontiguousarray(tri, dtype=np.float64)
        lo, hi = tri.reshape(-1, 3).min(0), tri.reshape(-1, 3).max(0)
        ext = np.maximum(hi - lo, 1e-6)
        lo, hi = lo - 1e-3 * ext.max(), hi + 1e-3 * ext.max()
        # cell size: ``cell_factor`` mean triangle extents (a surface mesh: a few triangles a cell)
        size = float(np.mean(np.ptp(tri, axis=1).max(1))) * cell_factor
        n = np.maximum(np.ceil((hi - lo) / size).astype(np.int64), 1)
        n = np.minimum(n, 256)
        self.lo, self.n = lo, n
        self.h = (hi - lo) / n
        b0 = np.clip(np.floor((tri.min(1) - lo) / self.h).astype(np.int64), 0, n - 1)
        b1 = np.clip(np.floor((tri.max(1) - lo) / self.h).astype(np.int64), 0, n - 1)
        self.start, self.items = _bin(b0, b1, n)
        self.tri = tri

    def occluded(self, X: np.ndarray, Y: np.ndarray, eps_start: float = 0.01, eps_end: float = 0.02) -> np.ndarray:
        """(N,) bool: the segment X[i] -> Y[i] meets a triangle more than ``eps_start`` mm after X
        and more than ``eps_end`` mm before Y."""
        out = np.zeros(len(X), dtype=np.bool_)
        _trace(np.ascontiguousarray(X, dtype=np.float64), np.ascontiguousarray(Y, dtype=np.float64), self.tri,
               self.lo, self.h, self.n, self.start, self.items, eps_start, eps_end, out)
        return out


@njit(cache=True)
def _bin(b0, b1, n):
    T = b0.shape[0]
    counts = np.zeros(n[0] * n[1] * n[2] + 1, dtype=np.int64)
    for t in range(T):
        for k in range(b0[t, 2], b1[t, 2] + 1):
            for j in range(b0[t, 1], b1[t, 1] + 1):
                for i in range(b0[t, 0], b1[t, 0] + 1):
                    counts[(k * n[1] + j) * n[0] + i + 1] += 1
    start = np.cumsum(counts)
    fill = start[:-1].copy()
    items = np.empty(start[-1], dtype=np.int64)
    for t in range(T):
        for k in range(b0[t, 2], b1[t, 2] + 1):
            for j in range(b0[t, 1], b1[t, 1] + 1):
                for i in range(b0[t, 0], b1[t, 0] + 1):
                    c = (k * n[1] + j) * n[0] + i
                    items[fill[c]] = t
                    fill[c] += 1
    return start, items


@njit(cache=True)
def _clip(ox, oy, oz, dx, dy, dz, lo, h, n, t0, t1):
    """[t0, t1] of the segment clipped to the grid's box (slabs); t0 > t1: outside."""
    o3 = (ox, oy, oz)
    d3 = (dx, dy, dz)
    for a in range(3):
        hi_a = lo[a] + h[a] * n[a]
        if abs(d3[a]) < 1e-300:
            if o3[a] < lo[a] or o3[a] > hi_a:
                return 1.0, 0.0
        else:
            ta, tb = (lo[a] - o3[a]) / d3[a], (hi_a - o3[a]) / d3[a]
            if ta > tb:
                ta, tb = tb, ta
            t0, t1 = max(t0, ta), min(t1, tb)
    return t0, t1


@njit(cache=True)
def _cell_hit(c, ox, oy, oz, dx, dy, dz, tri, start, items, t_lo, t_hi):
    """Whether a triangle binned in cell ``c`` meets the segment at t in (t_lo, t_hi)."""
    for q in range(start[c], start[c + 1]):
        t = items[q]
        v0x, v0y, v0z = tri[t, 0, 0], tri[t, 0, 1], tri[t, 0, 2]
        e1x, e1y, e1z = tri[t, 1, 0] - v0x, tri[t, 1, 1] - v0y, tri[t, 1, 2] - v0z
        e2x, e2y, e2z = tri[t, 2, 0] - v0x, tri[t, 2, 1] - v0y, tri[t, 2, 2] - v0z
        pvx, pvy, pvz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
        det = e1x * pvx + e1y * pvy + e1z * pvz
        if abs(det) < 1e-15:
            continue
        inv = 1.0 / det
        tvx, tvy, tvz = ox - v0x, oy - v0y, oz - v0z
        b1 = (tvx * pvx + tvy * pvy + tvz * pvz) * inv
        if b1 < 0.0 or b1 > 1.0:
            continue
        qvx, qvy, qvz = tvy * e1z - tvz * e1y, tvz * e1x - tvx * e1z, tvx * e1y - tvy * e1x
        b2 = (dx * qvx + dy * qvy + dz * qvz) * inv
        if b2 < 0.0 or b1 + b2 > 1.0:
            continue
        tt = (e2x * qvx + e2y * qvy + e2z * qvz) * inv
        if t_lo < tt < t_hi:
            return True
    return False


@njit(cache=True)
def _axis_start(o, d, lo, h, c):
    """DDA step, parameter increment per cell and parameter of the first cell boundary."""
    if abs(d) < 1e-300:
        return 1, 1e300, 1e300
    step = 1 if d > 0 else -1
    return step, h / abs(d), ((lo + (c + (1 if step > 0 else 0)) * h) - o) / d


@njit(cache=True, parallel=True)
def _trace(X, Y, tri, lo, h, n, start, items, eps_start, eps_end, out):
    for s in prange(X.shape[0]):
        ox, oy, oz = X[s, 0], X[s, 1], X[s, 2]
        dx, dy, dz = Y[s, 0] - ox, Y[s, 1] - oy, Y[s, 2] - oz
        L = np.sqrt(dx * dx + dy * dy + dz * dz)
        if L <= eps_start + eps_end:
            continue
        t_lo, t_hi = eps_start / L, 1.0 - eps_end / L
        t0, t1 = _clip(ox, oy, oz, dx, dy, dz, lo, h, n, t_lo, t_hi)
        if t0 > t1:
            continue
        ci = min(max(int((ox + t0 * dx - lo[0]) / h[0]), 0), n[0] - 1)
        cj = min(max(int((oy + t0 * dy - lo[1]) / h[1]), 0), n[1] - 1)
        ck = min(max(int((oz + t0 * dz - lo[2]) / h[2]), 0), n[2] - 1)
        si, tdx, tmx = _axis_start(ox, dx, lo[0], h[0], ci)
        sj, tdy, tmy = _axis_start(oy, dy, lo[1], h[1], cj)
        sk, tdz, tmz = _axis_start(oz, dz, lo[2], h[2], ck)
        hit = False
        while True:
            if _cell_hit((ck * n[1] + cj) * n[0] + ci, ox, oy, oz, dx, dy, dz, tri, start, items, t_lo, t_hi):
                hit = True
                break
            if min(tmx, tmy, tmz) > t1:
                break
            if tmx <= tmy and tmx <= tmz:
                ci += si
                tmx += tdx
                if ci < 0 or ci >= n[0]:
                    break
            elif tmy <= tmz:
                cj += sj
                tmy += tdy
                if cj < 0 or cj >= n[1]:
                    break
            else:
                ck += sk
                tmz += tdz
                if ck < 0 or ck >= n[2]:
                    break
        out[s] = hit
