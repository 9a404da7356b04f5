"""Projector pixels of board features from a local fit of the decoded projector coordinates.

A board feature (circle centre, checkerboard corner) is seen by the camera at ``q_cam``. The
projector pixel of the same board point is the value of the decoded projector-coordinate maps
``u_p(x, y)``, ``v_p(x, y)`` (from absolute phase, DESIGN.md) at ``q_cam``. A single-pixel read
would inherit the phase noise of one pixel and could not be taken at a sub-pixel position, so each
coordinate is fitted, around each feature, by a low-order polynomial in the camera pixel offset

    u_p(q_cam + d) ~ c0 + c1 dx + c2 dy + c3 dx^2 + c4 dx dy + c5 dy^2      (degree 2)

by weighted least squares over the valid pixels of an annulus ``inner_px <= |d| <= radius_px``
(the inner disc holds the feature's own dark circle, whose phase is noise). The camera-to-projector
map of a flat board is a homography, smooth at the scale of a window, so the polynomial bias is far
below the noise (the second-order term absorbs its curvature). The weights are the inverse phase
variances: the phase of an N-step set has variance ``2 sigma^2 / (N B^2)`` (B the modulation), so
the weight of a pixel is ``B^2``. Outlying pixels (a wrong fringe order, a speck) are rejected at
``reject_sigma`` robust standard deviations and the fit repeated.

Each fitted value comes with its standard error, ``s * sqrt([(A^T W A)^-1]_00)``, with ``s^2`` the
weighted residual variance (pixels taken as independent, as sensor noise is). That is the per-point
projector uncertainty the bundle adjustment weights by.

Quantised maps (Gray code alone, ``quantisation_px = b``): every camera pixel reads the centre of
its projector block, so its error is a sawtooth ``e(u) = centre(u) - u`` of the true coordinate
``u`` (period b, uniform over [-b/2, b/2), variance b^2/12). Neighbouring camera pixels that see
one block share almost the same error: the errors are not independent, and ``s^2 (A^T W A)^-1``
understates the error of the fitted value by a factor that grows with the camera pixels per
block (~3x on real Gray input). The standard error is then the exact variance of the fitted value
``c0 = beta . y`` (``beta`` the first row of ``(A^T W A)^-1 A^T W``) over a random placement of
the block grid relative to the feature: with the sawtooth's Fourier series
``e(u) = sum_k (b / (pi k)) sin(2 pi k u / b + phase)``,

    var(c0) = sum_k  b^2 / (2 pi^2 k^2) |sum_i beta_i exp(2 pi i k u_i / b)|^2

(``u_i`` the fitted coordinate at pixel i; k = 1..64, the rest of the series as independent
errors), plus the residual variance beyond b^2/12 (decoding noise) as independent pixel noise.

SYNOPSIS

    >>> import numpy as np
    >>> from calib.detect.marker_phase import fit_projector_points
    >>> yy, xx = np.mgrid[0:60, 0:80].astype(float)
    >>> u_map = 100 + 2.0 * xx + 0.5 * yy          # projector columns, px
    >>> v_map = 50 - 0.25 * xx + 3.0 * yy
    >>> fit = fit_projector_points(np.array([[40.3, 30.7]]), u_map, v_map, radius_px=8.0)
    >>> np.round(fit.q_prj, 6).tolist()
    [[195.95, 132.025]]
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import MarkerPhaseError


@dataclass
class ProjectorPointFit:
    """Projector pixels of N camera features.

    - q_prj: (N, 2) projector pixels (u_p, v_p), NaN where the fit failed.
    - sigma_prj: (N, 2) standard error of each coordinate, px (NaN where failed).
    - n_pixels: (N, 2) pixels used per coordinate after rejection.
    - rejected: (N, 2) pixels rejected as outliers per coordinate.
    - rms_px: (N, 2) weighted RMS residual of the local fit, projector px.
    - ok: (N,) bool, both coordinates fitted.
    - reasons: {index: message} for each failed feature.
    - dq_prj_dq_cam: (N, 2, 2) gradient of the fitted projector coordinates at the feature,
      ``[[du_p/dx, du_p/dy], [dv_p/dx, dv_p/dy]]`` (projector px per camera px; NaN where failed):
      how an error in the camera pixel carries into the projector pixel read there.
    """

    q_prj: np.ndarray
    sigma_prj: np.ndarray
    n_pixels: np.ndarray
    rejected: np.ndarray
    rms_px: np.ndarray
    ok: np.ndarray
    reasons: dict = field(default_factory=dict)
    dq_prj_dq_cam: np.ndarray | None = None

    @property
    def sigma_point(self) -> np.ndarray:
        """(N,) one standard deviation per point: the RMS of the two coordinates' errors (px)."""
        return np.sqrt(0.5 * np.sum(self.sigma_prj ** 2, axis=1))


N_TERMS = {1: 3, 2: 6}
SAWTOOTH_TERMS = 64
"""Fourier terms of the quantisation sawtooth summed exactly; the rest is taken as independent."""


def quantisation_variance(beta, u, block_px: float) -> float:
    """Variance of ``beta . e`` where ``e_i`` is the quantisation error (block centre minus true
    value, block ``block_px``) at true coordinates ``u_i``, over a uniformly random block phase
    (module docstring). beta, u: (n,); returns projector px^2.

    >>> import numpy as np
    >>> round(quantisation_variance(np.array([1.0]), np.array([0.3]), 1.0), 6)   # one pixel: b^2/12
    0.083333
    """
    beta = np.asarray(beta, dtype=np.float64)
    k = np.arange(1, SAWTOOTH_TERMS + 1, dtype=np.float64)
    phase = 2 * np.pi * np.outer(k, np.asarray(u, dtype=np.float64)) / block_px
    power = np.abs(np.exp(1j * phase) @ beta) ** 2
    amp2 = block_px ** 2 / (2 * np.pi ** 2 * k ** 2)
    tail = block_px ** 2 / 12 - float(amp2.sum())
    return float(amp2 @ power + tail * (beta @ beta))


def _design_matrix(dx: np.ndarray, dy: np.ndarray, degree: int) -> np.ndarray:
    cols = [np.ones_like(dx), dx, dy]
    if degree == 2:
        cols += [dx * dx, dx * dy, dy * dy]
    return np.stack(cols, axis=1)


def _fit_one(dx, dy, values, weights, degree, reject_sigma, min_pixels, block_px=None):
    """Weighted polynomial fit of ``values`` at offsets (dx, dy) (px, already scaled); returns
    (value at 0, standard error, n used, n rejected, weighted rms, gradient at 0 (2,) per scaled
    unit) or a failure string. ``block_px``: the values are quantised to blocks of that size
    (standard error from :func:`quantisation_variance`)."""
    keep = np.ones(len(values), bool)
    n_terms = N_TERMS[degree]
    for _ in range(3):
        n = int(keep.sum())
        if n < max(min_pixels, n_terms + 2):
            return f"{n} usable pixels (need {max(min_pixels, n_terms + 2)})"
        A = _design_matrix(dx[keep], dy[keep], degree)
        w = weights[keep]
        sw = np.sqrt(w)
        Aw = A * sw[:, None]
        bw = values[keep] * sw
        try:
            coef, *_ = np.linalg.lstsq(Aw, bw, rcond=None)
            cov_unit = np.linalg.inv(Aw.T @ Aw)
        except np.linalg.LinAlgError:
            return "window geometry is degenerate (pixels on a line)"
        r_all = (values - _design_matrix(dx, dy, degree) @ coef) * np.sqrt(weights)
        dof = n - n_terms
        s2 = float(np.sum(r_all[keep] ** 2) / dof)
        mad = 1.4826 * float(np.median(np.abs(r_all[keep])))
        scale = max(mad, 1e-12)
        new_keep = np.abs(r_all) <= reject_sigma * scale
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    if not np.isfinite(cov_unit[0, 0]) or cov_unit[0, 0] < 0:
        return "fit covariance is not finite"
    # s2 is the variance of a unit-weight residual; weights are normalised to mean 1 by the caller
    sigma = float(np.sqrt(s2 * cov_unit[0, 0]))
    if block_px:
        A = _design_matrix(dx[keep], dy[keep], degree)
        beta = (cov_unit @ (A * weights[keep][:, None]).T)[0]
        noise = max(s2 - block_px ** 2 / 12, 0.0) * cov_unit[0, 0]
        sigma = float(np.sqrt(quantisation_variance(beta, A @ coef, block_px) + noise))
    rms = float(np.sqrt(np.sum(r_all[keep] ** 2) / np.sum(weights[keep])))
    return float(coef[0]), sigma, int(keep.sum()), int(len(values) - keep.sum()), rms, coef[1:3].copy()


def _prepared_maps(items, exclude) -> dict:
    """{name: (map, usable (H, W) bool, weight (H, W))} of the coordinate maps given, checked."""
    maps = {}
    shape = None
    for name, m, valid, weight in items:
        if m is None:
            continue
        m = np.asarray(m, dtype=np.float64)
        if m.ndim != 2:
            raise MarkerPhaseError(f"{name}_map: expected a 2-D (H, W) map, got shape {m.shape}")
        if shape is not None and m.shape != shape:
            raise MarkerPhaseError(f"u_map and v_map differ in shape: {shape} vs {m.shape}")
        shape = m.shape
        ok = np.isfinite(m)
        if valid is not None:
            valid = np.asarray(valid, bool)
            if valid.shape != m.shape:
                raise MarkerPhaseError(f"valid_{name}: shape {valid.shape}, map has {m.shape}")
            ok &= valid
        if weight is None:
            w = np.ones(m.shape)
        else:
            w = np.asarray(weight, dtype=np.float64)
            if w.shape != m.shape:
                raise MarkerPhaseError(f"weight_{name}: shape {w.shape}, map has {m.shape}")
            w = np.where(np.isfinite(w) & (w > 0), w, 0.0)
        if exclude is not None:
            ok &= ~np.asarray(exclude, bool)
        ok &= w > 0
        maps[name] = (m, ok, w)
    if not maps:
        raise MarkerPhaseError("neither u_map nor v_map given")
    return maps


def _fit_feature(x, y, r, inner, maps, degree, reject_sigma, min_pixels, quantisation=(None, None)):
    """The fits of one feature at camera pixel (x, y), window radii ``r`` / ``inner``: yields
    (coordinate index j, (value, sigma, n used, n rejected, rms, gradient (2,) per camera px) or
    a failure message)."""
    H, W = next(iter(maps.values()))[0].shape
    x0, x1 = max(int(np.floor(x - r)), 0), min(int(np.ceil(x + r)), W - 1)
    y0, y1 = max(int(np.floor(y - r)), 0), min(int(np.ceil(y + r)), H - 1)
    if x0 > x1 or y0 > y1:
        yield 0, f"window around ({x:.1f}, {y:.1f}) lies outside the {W}x{H} image"
        return
    yy, xx = np.mgrid[y0:y1 + 1, x0:x1 + 1]
    dx = xx - x
    dy = yy - y
    d2 = dx * dx + dy * dy
    ring = (d2 <= r * r) & (d2 >= inner ** 2)
    for j, name in enumerate(("u", "v")):
        if name not in maps:
            continue
        m, ok, w = maps[name]
        sel = ring & ok[y0:y1 + 1, x0:x1 + 1]
        wv = w[y0:y1 + 1, x0:x1 + 1][sel]
        if wv.size == 0:
            yield j, f"{name}_p: no valid decoded pixel within {r:.1f} px of ({x:.1f}, {y:.1f})"
            continue
        wv = wv / wv.mean()
        out = _fit_one(dx[sel] / r, dy[sel] / r, m[y0:y1 + 1, x0:x1 + 1][sel], wv, degree, reject_sigma, min_pixels,
                       quantisation[j])
        if isinstance(out, str):
            yield j, f"{name}_p: {out} within {r:.1f} px of ({x:.1f}, {y:.1f})"
            continue
        yield j, out[:5] + (out[5] / r,)


def fit_projector_points(q_cam, u_map, v_map, *, valid_u=None, valid_v=None, weight_u=None, weight_v=None,
                         radius_px=10.0, inner_px=0.0, degree: int = 2, reject_sigma: float = 4.0,
                         min_pixels: int = 12, exclude=None, quantisation_px=None) -> ProjectorPointFit:
    """Fit the projector pixel of every camera feature.

    ARGUMENTS
    - q_cam: (N, 2) camera pixels (x right, y down; pixel centres at integers).
    - u_map, v_map: (H, W) decoded projector column / row coordinate of every camera pixel (px,
      float64; NaN where invalid). Either may be None (that coordinate is then NaN).
    - valid_u, valid_v: optional (H, W) bool masks (default: finite values).
    - weight_u, weight_v: optional (H, W) inverse-variance weights (use the squared modulation B^2
      of the finest fringe set); default equal weights.
    - radius_px: scalar or (N,) outer radius of each window, camera px.
    - inner_px: scalar or (N,) inner radius excluded (the feature's own dark circle), camera px.
    - degree: 1 (affine) or 2 (quadratic) local model.
    - reject_sigma: outlier pixels beyond this many robust sigmas are dropped and the fit repeated.
    - min_pixels: fewer usable pixels than this and the feature fails (reason recorded).
    - exclude: optional (H, W) bool mask of pixels never to use (e.g. other features' circles).
    - quantisation_px: None (phase-shift maps), or the block size (px) of quantised maps (Gray
      code alone): a scalar for both, or ``(u, v)`` with None for an unquantised one. The standard
      errors then model the quantisation (module docstring).

    RETURNS a :class:`ProjectorPointFit`.
    """
    q_cam = np.asarray(q_cam, dtype=np.float64)
    if q_cam.ndim != 2 or q_cam.shape[1] != 2:
        raise MarkerPhaseError(f"q_cam: expected shape (N, 2), got {q_cam.shape}")
    if degree not in N_TERMS:
        raise MarkerPhaseError(f"degree: expected 1 or 2, got {degree!r}")
    maps = _prepared_maps((("u", u_map, valid_u, weight_u), ("v", v_map, valid_v, weight_v)), exclude)
    n = len(q_cam)
    radius = np.broadcast_to(np.asarray(radius_px, dtype=np.float64), (n,))
    inner = np.broadcast_to(np.asarray(inner_px, dtype=np.float64), (n,))
    if np.any(~np.isfinite(radius)) or np.any(radius <= 0) or np.any(inner < 0) or np.any(inner >= radius):
        raise MarkerPhaseError("window radii: need 0 <= inner_px < radius_px, finite")
    quant = tuple(quantisation_px) if isinstance(quantisation_px, (tuple, list)) else (quantisation_px,) * 2
    if len(quant) != 2 or any(b is not None and not (np.isfinite(b) and b > 0) for b in quant):
        raise MarkerPhaseError(f"quantisation_px: expected None, a block size > 0 or (u, v), got {quantisation_px!r}")

    q_prj = np.full((n, 2), np.nan)
    sigma = np.full((n, 2), np.nan)
    n_pix = np.zeros((n, 2), int)
    n_rej = np.zeros((n, 2), int)
    rms = np.full((n, 2), np.nan)
    grad = np.full((n, 2, 2), np.nan)
    reasons = {}
    for i, (x, y) in enumerate(q_cam):
        if not (np.isfinite(x) and np.isfinite(y)):
            reasons[i] = "camera point is not finite"
            continue
        for j, out in _fit_feature(x, y, radius[i], inner[i], maps, degree, reject_sigma, min_pixels, quant):
            if isinstance(out, str):
                reasons[i] = out
                continue
            q_prj[i, j], sigma[i, j], n_pix[i, j], n_rej[i, j], rms[i, j], grad[i, j] = out
    cols = [j for j, name in enumerate(("u", "v")) if name in maps]
    ok_all = np.all(np.isfinite(q_prj[:, cols]), axis=1)
    return ProjectorPointFit(q_prj, sigma, n_pix, n_rej, rms, ok_all, reasons, grad)


def window_radii(q_cam, feature_px, *, fraction_of_spacing: float = 0.45, inner_factor: float = 1.6,
                 inner_margin_px: float = 1.5, min_radius_px: float = 4.0):
    """Window radii for :func:`fit_projector_points` from the detected layout.

    The outer radius is ``fraction_of_spacing`` of the distance to the nearest other feature (so a
    window never reaches a neighbour's circle); the inner radius excludes the feature's own circle
    with a blur margin: ``inner_factor * feature_px + inner_margin_px`` (0 for features with no
    dark area of their own: pass ``feature_px = 0``). Returns (radius (N,), inner (N,)) in px.
    """
    q = np.asarray(q_cam, dtype=np.float64)
    f = np.broadcast_to(np.asarray(feature_px, dtype=np.float64), (len(q),))
    if len(q) < 2:
        raise MarkerPhaseError("window_radii needs at least 2 features to measure their spacing")
    d = np.sqrt(((q[:, None, :] - q[None, :, :]) ** 2).sum(-1))
    np.fill_diagonal(d, np.inf)
    nearest = d.min(axis=1)
    radius = np.maximum(fraction_of_spacing * nearest, min_radius_px)
    inner = np.where(f > 0, inner_factor * f + inner_margin_px, 0.0)
    inner = np.minimum(inner, 0.6 * radius)
    return radius, inner
