"""Grow a 2-D lattice through blob centres: integer cells (i, j) for the blobs that lie on it.

The image of a planar square grid is locally a parallelogram lattice. From a seed blob with a
Gauss-reduced pair of neighbour vectors, cells are predicted from the already assigned cells
around them (local homography with >= 6 neighbours, else a local affine map, else the seed basis)
and take the nearest free blob within 0.3 local spacings. Cells up to two steps from the grown
part are tried, so a missing row (a saturated patch, a lost circle) does not stop the growth.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..zhang import homography


def _reduced_basis(vectors):
    """Two shortest independent vectors of a lattice from candidate neighbour vectors (K, 2)."""
    order = np.argsort(np.linalg.norm(vectors, axis=1))
    a = vectors[order[0]]
    b = None
    for k in order[1:]:
        v = vectors[k]
        s = abs(a[0] * v[1] - a[1] * v[0]) / (np.linalg.norm(a) * np.linalg.norm(v))
        if s > 0.5:
            b = v
            break
    if b is None:
        return None
    for _ in range(10):  # Lagrange-Gauss reduction
        if np.dot(b, b) < np.dot(a, a):
            a, b = b, a
        m = np.round(np.dot(a, b) / np.dot(a, a))
        if m == 0:
            break
        b = b - m * a
    return a, b


def _choose_seed(xy, tree):
    """A blob near the middle whose 4 nearest neighbours look like a lattice cross."""
    k = min(9, len(xy))
    dist, idx = tree.query(xy, k=k)
    centre = np.median(xy, axis=0)
    order = np.argsort(np.linalg.norm(xy - centre, axis=1))
    for s in order[: max(10, len(xy) // 4)]:
        vec = xy[idx[s, 1:]] - xy[s]
        basis = _reduced_basis(vec)
        if basis is None:
            continue
        a, b = basis
        hits = 0
        for v in (a, -a, b, -b):
            d, _ = tree.query(xy[s] + v)
            hits += d < 0.25 * np.linalg.norm(a)
        if hits >= 3:
            return int(s), a, b
    return None


def _local_map(cells, pts, target):
    """Predict the image position of ``target`` (i, j) and the local spacing from nearby cells."""
    for radius in (2, 3, 4):
        near = np.max(np.abs(cells - target), axis=1) <= radius
        if near.sum() >= 3:
            break
    c, p = cells[near].astype(float), pts[near]
    cc = c - c.mean(axis=0)
    rank = np.linalg.matrix_rank(cc, tol=1e-9) if len(c) >= 3 else 0
    if rank == 2 and len(c) >= 6:
        try:
            Hm = homography(c, p)
            t = Hm @ np.array([target[0], target[1], 1.0])
            if abs(t[2]) > 1e-12:
                J = np.array([(Hm @ np.array([target[0] + di, target[1] + dj, 1.0])) for di, dj in ((1, 0), (0, 1))])
                J = J[:, :2] / J[:, 2:3] - t[:2] / t[2]
                return t[:2] / t[2], float(np.min(np.linalg.norm(J, axis=1)))
        except np.linalg.LinAlgError:
            pass
    if rank == 2:
        A = np.c_[c, np.ones(len(c))]
        coef = np.linalg.lstsq(A, p, rcond=None)[0]
        return np.array([target[0], target[1], 1.0]) @ coef, float(np.min(np.linalg.norm(coef[:2], axis=1)))
    return None


def grow_lattice(xy: np.ndarray, max_cells: int = 100000):
    """Assign integer cells to the blobs (M, 2) that lie on one lattice.

    RETURNED VALUE: (cells (M, 2) int with -huge for unassigned blobs, assigned (M,) bool,
    basis (2, 2) image vectors of the unit steps in i and j at the seed), or None when no
    lattice is found (fewer than 5 blobs or no lattice-like neighbourhood).
    """
    M = len(xy)
    if M < 5:
        return None
    tree = cKDTree(xy)
    seed = _choose_seed(xy, tree)
    if seed is None:
        return None
    s, a, b = seed
    cell_of = {s: (0, 0)}
    blob_at = {(0, 0): s}
    # the seed cross, from the basis directly
    for (di, dj), v in (((1, 0), a), ((-1, 0), -a), ((0, 1), b), ((0, -1), -b)):
        d, k = tree.query(xy[s] + v)
        if d < 0.3 * np.linalg.norm(a) and k not in cell_of:
            cell_of[int(k)] = (di, dj)
            blob_at[(di, dj)] = int(k)
    tried = {}
    changed = True
    while changed and len(blob_at) < max_cells:
        changed = False
        cells = np.array(list(blob_at.keys()))
        pts = xy[np.array(list(blob_at.values()))]
        frontier = set()
        for (i, j) in blob_at:
            for di in range(-2, 3):
                for dj in range(-2, 3):
                    c = (i + di, j + dj)
                    if c not in blob_at:
                        frontier.add(c)
        # most-supported cells first
        scored = []
        for c in frontier:
            support = int(np.sum(np.max(np.abs(cells - c), axis=1) <= 1))
            if support == 0 and tried.get(c, -1) >= 0:
                continue
            n2 = int(np.sum(np.max(np.abs(cells - c), axis=1) <= 2))
            if tried.get(c, -1) >= n2:
                continue
            scored.append((-support, -n2, c))
        scored.sort()
        for _, negn2, c in scored:
            tried[c] = -negn2
            pred = _local_map(cells, pts, np.array(c))
            if pred is None:
                continue
            p, spacing = pred
            d, k = tree.query(p)
            if d < 0.3 * spacing and int(k) not in cell_of:
                cell_of[int(k)] = c
                blob_at[c] = int(k)
                changed = True
        # refresh arrays each pass (new cells help predictions of the next pass)
    out = np.full((M, 2), np.iinfo(np.int64).min // 4, dtype=np.int64)
    assigned = np.zeros(M, bool)
    for k, c in cell_of.items():
        out[k] = c
        assigned[k] = True
    return out, assigned, np.stack([a, b], axis=1)
