"""Circle candidates in a grey image and their sub-pixel centres.

Pipeline: a local background (grey closing for dark blobs, opening for light ones, with a kernel
larger than the largest blob, grown until it is), a contrast image ``d`` (ink coverage scale:
``(bg - I) / bg`` for dark-on-light, ``(I - bg) / bg_scale`` for light-on-dark), connected
components above a threshold from the noise level and the peak contrast, then per blob:

- ``"moments"``: the centroid and second moments of ``d`` over the blob's support, with the
  background re-estimated as a plane on a ring around it (the centroid of the ink coverage is the
  centre of the imaged ellipse; the noise adds no bias because ``d`` is not clipped);
- ``"edge"``: sub-pixel half-contrast crossings along rays from the moment centre and a direct
  least-squares ellipse fit (Halir & Flusser's stable form of Fitzgibbon's fit) to them.

Coordinates are pixels, x right, y down, pixel centres at integers. All float64.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import map_coordinates

from ..errors import DetectionError

CENTRE_METHODS = ("moments", "edge")


@dataclass
class Blobs:
    """Candidates (M of them) found in one image.

    - xy: (M, 2) ellipse centres (px); axes: (M, 2) semi-axes (major, minor) px; angle: (M,) rad.
    - area: (M,) thresholded pixel count; contrast: (M,) peak contrast (fraction of background).
    - cut: (M,) bool, the blob touches the image border or the unlit region (incomplete).
    - notes: what was adapted while finding them.
    """

    xy: np.ndarray
    axes: np.ndarray
    angle: np.ndarray
    area: np.ndarray
    contrast: np.ndarray
    cut: np.ndarray
    kernel_px: int
    notes: list

    def __len__(self):
        return int(self.xy.shape[0])

    @property
    def size(self) -> np.ndarray:
        """(M,) mean semi-axis (px)."""
        return self.axes.mean(axis=1)


def _odd(k: float) -> int:
    k = int(round(k))
    return k + 1 if k % 2 == 0 else k


def contrast_image(f: np.ndarray, dark_blobs: bool, kernel: int):
    """Background-normalised contrast ``d`` (blobs positive), background and lit mask."""
    se = cv2.getStructuringElement(cv2.MORPH_RECT, (kernel, kernel))
    f32 = f.astype(np.float32)  # float32 suffices for the background envelope (smoothed below)
    op = cv2.MORPH_CLOSE if dark_blobs else cv2.MORPH_OPEN
    bg = cv2.morphologyEx(f32, op, se, borderType=cv2.BORDER_REPLICATE).astype(np.float64)
    bg = cv2.GaussianBlur(bg, (0, 0), kernel / 6.0)
    hi = float(np.percentile(bg, 99.0))
    if dark_blobs:
        lit = bg > 0.2 * hi
        d = np.where(lit, (bg - f) / np.maximum(bg, 1e-12), 0.0)
    else:
        lit = np.ones_like(bg, bool)
        scale = max(float(np.percentile(f, 99.9)) - float(np.percentile(bg, 50.0)), 1e-12)
        d = (f - bg) / scale
    return d, bg, lit


def _noise_sigma(d: np.ndarray, lit: np.ndarray) -> float:
    v = d[lit]
    if v.size > 200000:
        v = v[:: v.size // 200000]
    med = np.median(v)
    return float(1.4826 * np.median(np.abs(v - med))) + 1e-6


def _fit_plane(x, y, v):
    """Robust plane a + b x + c y through samples (two passes, 3-MAD trimming)."""
    A = np.c_[np.ones_like(x), x, y]
    keep = np.ones(v.size, bool)
    coef = np.array([np.median(v), 0.0, 0.0])
    for _ in range(2):
        if keep.sum() < 6:
            break
        coef = np.linalg.lstsq(A[keep], v[keep], rcond=None)[0]
        r = v - A @ coef
        s = 1.4826 * np.median(np.abs(r[keep])) + 1e-12
        keep = np.abs(r) < 3 * s + 1e-9
    return coef


def fit_ellipse_direct(x, y):
    """Direct least-squares ellipse through (x, y) (Halir & Flusser 1998); returns
    (centre (2,), semi-axes (major, minor), angle rad) or None when not an ellipse."""
    mx, my = x.mean(), y.mean()
    s = max(np.std(x), np.std(y), 1e-12)
    xn, yn = (x - mx) / s, (y - my) / s
    D1 = np.c_[xn * xn, xn * yn, yn * yn]
    D2 = np.c_[xn, yn, np.ones_like(xn)]
    S1, S2, S3 = D1.T @ D1, D1.T @ D2, D2.T @ D2
    try:
        T = -np.linalg.solve(S3, S2.T)
    except np.linalg.LinAlgError:
        return None
    M = S1 + S2 @ T
    M = np.array([M[2] / 2, -M[1], M[0] / 2])
    w, V = np.linalg.eig(M)
    V = np.real(V)
    cond = 4 * V[0] * V[2] - V[1] ** 2
    ok = np.nonzero(cond > 0)[0]
    if ok.size == 0:
        return None
    a1 = V[:, ok[0]]
    a, b, c = a1
    d, e, g = T @ a1
    # back to pixel units: conic in normalised coords -> centre, axes
    A2 = np.array([[a, b / 2], [b / 2, c]])
    try:
        cn = np.linalg.solve(A2, -0.5 * np.array([d, e]))
    except np.linalg.LinAlgError:
        return None
    k = -(cn @ A2 @ cn + d * cn[0] + e * cn[1] + g)
    lam, vec = np.linalg.eigh(A2 / k)
    if np.any(lam <= 0):
        return None
    axes = s / np.sqrt(lam)          # ascending lam -> major first
    angle = float(np.arctan2(vec[1, 0], vec[0, 0]))
    return np.array([mx + s * cn[0], my + s * cn[1]]), np.array([axes[0], axes[1]]), angle


def _refine(d, f, comp_mask, x0, y0, bg_dark, lit, method, n_rays=48):
    """Centre, axes, angle, peak contrast of one blob from its window (see module docstring)."""
    h, w = comp_mask.shape
    ys, xs = np.nonzero(comp_mask)
    size = max(np.ptp(xs), np.ptp(ys)) + 1
    grow = 2 + int(round(0.25 * size))
    support = cv2.dilate(comp_mask.astype(np.uint8), cv2.getStructuringElement(
        cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1))).astype(bool)
    ring = cv2.dilate(support.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool) & ~support
    ring &= lit
    yy, xx = np.mgrid[0:h, 0:w]
    if ring.sum() >= 8:
        coef = _fit_plane(xx[ring].astype(float), yy[ring].astype(float), f[ring])
        bgp = coef[0] + coef[1] * xx + coef[2] * yy
    else:
        bgp = None
    if bgp is not None and bg_dark:
        dd = (bgp - f) / np.maximum(bgp, 1e-12)
    elif bgp is not None:
        dd = (f - bgp) / max(float(np.median(bgp)) + float(np.max(f[support]) - np.median(bgp)), 1e-12)
    else:
        dd = d
    wgt = np.where(support, dd, 0.0)
    s0 = wgt.sum()
    if not s0 > 0:
        return None
    cx = (wgt * xx).sum() / s0
    cy = (wgt * yy).sum() / s0
    dx, dy = xx - cx, yy - cy
    cov = np.array([[(wgt * dx * dx).sum(), (wgt * dx * dy).sum()],
                    [(wgt * dx * dy).sum(), (wgt * dy * dy).sum()]]) / s0
    lam, vec = np.linalg.eigh(cov)
    if lam[0] <= 0:
        return None
    axes = 2.0 * np.sqrt(lam[::-1])
    angle = float(np.arctan2(vec[1, 1], vec[0, 1]))
    peak = float(np.percentile(dd[comp_mask], 90))
    centre = np.array([cx, cy])
    if method == "edge":
        level = 0.5 * peak
        rmax = 2.0 * axes[0] + 2
        r = np.linspace(0, rmax, int(np.ceil(rmax / 0.1)) + 1)
        th = np.linspace(0, 2 * np.pi, n_rays, endpoint=False)
        X = cx + np.cos(th)[:, None] * r[None]
        Y = cy + np.sin(th)[:, None] * r[None]
        prof = map_coordinates(dd, [Y.ravel(), X.ravel()], order=1, mode="nearest").reshape(X.shape)
        pts = []
        for k in range(n_rays):
            below = np.nonzero(prof[k] < level)[0]
            if below.size == 0 or below[0] == 0:
                continue
            j = below[0]
            p0, p1 = prof[k, j - 1], prof[k, j]
            t = (p0 - level) / (p0 - p1)
            rr = r[j - 1] + t * (r[j] - r[j - 1])
            pts.append((cx + np.cos(th[k]) * rr, cy + np.sin(th[k]) * rr))
        if len(pts) >= 8:
            pts = np.asarray(pts)
            fit = fit_ellipse_direct(pts[:, 0], pts[:, 1])
            if fit is not None and np.hypot(*(fit[0] - centre)) < 0.5 * axes[1] + 1:
                centre, axes, angle = fit[0], fit[1], fit[2]
    return centre, axes, angle, peak


def find_blobs(f: np.ndarray, dark_blobs: bool, *, method: str = "moments", kernel: int | None = None) -> Blobs:
    """Blob candidates of a grey float image (see module docstring). ``dark_blobs``: the circles
    are darker than the board. ``method``: "moments" or "edge" (centre estimator)."""
    if method not in CENTRE_METHODS:
        raise DetectionError(f"centre method: expected one of {CENTRE_METHODS}, got {method!r}")
    H, W = f.shape
    notes = []
    k = kernel or _odd(max(15, min(H, W) / 12))
    for _ in range(4):
        d, bg, lit = contrast_image(f, dark_blobs, k)
        sigma = _noise_sigma(d, lit)
        peak = float(np.percentile(d[lit], 99.95)) if lit.any() else 0.0
        thr = max(5.0 * sigma, 0.3 * peak, 1e-3)
        mask = ((d > thr) & lit).astype(np.uint8)
        n, lab, stats, cent = cv2.connectedComponentsWithStats(mask, connectivity=8)
        dims = np.maximum(stats[1:, cv2.CC_STAT_WIDTH], stats[1:, cv2.CC_STAT_HEIGHT])
        area = stats[1:, cv2.CC_STAT_AREA]
        # blob-like components: filled enough; the largest decides whether the kernel was big enough
        fill = area / np.maximum(dims.astype(float) ** 2, 1)
        bloblike = (area >= 3) & (fill > 0.3)
        biggest = int(dims[bloblike].max()) if bloblike.any() else 0
        if biggest > 0.6 * k and k < min(H, W) // 2:
            k = _odd(min(2.2 * biggest + 5, min(H, W) // 2))
            notes.append(f"background kernel grown to {k} px for blobs up to {biggest} px")
            continue
        break
    unlit = ~lit
    if unlit.any():
        unlit = cv2.dilate(unlit.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    out = {key: [] for key in ("xy", "axes", "angle", "area", "contrast", "cut")}
    for i in np.nonzero(bloblike)[0]:
        x, y, w, h = (int(v) for v in stats[i + 1, :4])
        if max(w, h) > 0.6 * k:
            continue
        cut = x == 0 or y == 0 or x + w == W or y + h == H
        m = 3 + int(round(0.6 * max(w, h)))
        x0, y0, x1, y1 = max(x - m, 0), max(y - m, 0), min(x + w + m, W), min(y + h + m, H)
        comp = lab[y0:y1, x0:x1] == i + 1
        if unlit[y:y + h, x:x + w].any():
            cut = True
        res = _refine(d[y0:y1, x0:x1], f[y0:y1, x0:x1], comp, x0, y0, dark_blobs, lit[y0:y1, x0:x1], method)
        if res is None:
            continue
        c, axes, ang, pk = res
        if axes[0] > 5 * axes[1]:
            continue  # a line or an edge, not a circle seen at <= ~78 deg
        out["xy"].append(c + [x0, y0])
        out["axes"].append(axes)
        out["angle"].append(ang)
        out["area"].append(int(area[i]))
        out["contrast"].append(pk)
        out["cut"].append(cut)
    arr = {key: np.asarray(v, dtype=np.float64) for key, v in out.items()}
    return Blobs(arr["xy"].reshape(-1, 2), arr["axes"].reshape(-1, 2), arr["angle"], arr["area"],
                 arr["contrast"], arr["cut"].astype(bool), k, notes)
