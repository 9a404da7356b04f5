"""``residuals.png``, the summary figure ``calib run`` draws by default: per device, the residual
scatter coloured by view, the per-view RMS and the residual distribution beside a Gaussian's with
the rejection threshold, drawn with Pillow (:mod:`calib.io.raster_plot`), not matplotlib: the
figure then costs ~0.1 s instead of ~1 s (matplotlib's import and axes; docs/speed.md).

    from calib.io.summary_figure import summary_figure
    summary_figure(run.calibration, fitted, "out/residuals.png")   # fitted: obs as the adjustment weighted them
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from unwrap.safe_output import atomic_path

from .raster_plot import BLACK, C0, RED, Canvas, viridis

#: One panel's cell, final pixels (the matplotlib figure it replaces: 5 x 4 in at 90 dpi).
CELL_W, CELL_H = 450, 360
#: Panel margins (left, right, top, bottom), final pixels: tick labels and the axis label on the
#: left and below, the title above.
MARGINS = (80, 20, 45, 52)
#: The PNG: reduced to a 256-colour palette (octree: a flat-coloured figure loses nothing visible)
#: and zlib level 1: ~30 ms and ~40 kB at 9 views, against ~70 ms and 80 kB for RGB at level 1
#: (whose row filters cost more than the compression) and ~95 ms for RGB at the default level 6.
PNG_COLOURS, PNG_COMPRESS_LEVEL = 256, 1


def distribution(cal, obs, device: str, sigma_pt=None):
    """|e| / robust sigma of ``device``'s points, e the residual normalised by the point's sigma,
    the robust sigma from the median of the kept points' squared values (Rayleigh: median of
    z^2 = 2 ln 2). ``sigma_pt``: :func:`calib.calibrate.sigma_of_points` when already computed.
    Returns (z (n,), kept (n,) bool)."""
    from ..calibrate import sigma_of_points

    ba = cal.ba
    m = ba.point_device == device
    sig = sigma_of_points(obs, ba) if sigma_pt is None else sigma_pt
    e = np.linalg.norm(ba.residuals_px[m], axis=1) / sig[m]
    sigma = np.sqrt(np.median(e[ba.inlier[m]] ** 2) / (2 * np.log(2))) if ba.inlier[m].any() else np.nan
    if not sigma > 0:           # noise-free (all kept residuals 0) or nothing kept: |e| unnormalised
        sigma = 1.0
    return e / sigma, ba.inlier[m]


def _equal_aspect(x, y, w: float, h: float, margin: float = 0.05):
    """Data ranges around (x, y) (``margin`` of the span on each side) widened so that one unit
    is as long on x as on y in a ``w`` x ``h`` pixel rectangle."""
    lo = np.array([x.min(), y.min()]) if len(x) else np.array([-1.0, -1.0])
    hi = np.array([x.max(), y.max()]) if len(x) else np.array([1.0, 1.0])
    span = np.maximum(hi - lo, 1e-12)
    lo, hi = lo - margin * span, hi + margin * span
    scale = max((hi[0] - lo[0]) / w, (hi[1] - lo[1]) / h)
    mid = (lo + hi) / 2
    return (mid[0] - scale * w / 2, mid[0] + scale * w / 2), (mid[1] - scale * h / 2, mid[1] + scale * h / 2)


def summary_figure(cal, obs, path) -> Path:
    """Draw the summary figure of calibration ``cal`` (its ``ba``: residuals_px (P, 2) px,
    point_device, point_view, inlier, stats) on observations ``obs`` (as the adjustment weighted
    them) and write it to ``path`` atomically (PNG; a failed write leaves the previous file).
    Columns: the devices in ``cal.ba.stats``; rows: residual scatter (du, dv px; colour: view,
    viridis; rejected points red crosses), per-view RMS (px), distribution of |e| / robust sigma
    (log counts) beside the Rayleigh density of a Gaussian, the rejection threshold dashed."""
    ba = cal.ba
    devices = [d for d in ("camera", "projector") if d in ba.stats]
    n_views = len(ba.stats["views"])
    canvas = Canvas(CELL_W * len(devices), CELL_H * 3)
    w, h = (CELL_W - MARGINS[0] - MARGINS[1]), (CELL_H - MARGINS[2] - MARGINS[3])
    sigma_pt = None
    for k, d in enumerate(devices):
        cell = lambda row: (k * CELL_W, row * CELL_H, CELL_W, CELL_H)  # noqa: E731
        m = ba.point_device == d
        keep, out = m & ba.inlier, m & ~ba.inlier
        r = ba.residuals_px
        xlim, ylim = _equal_aspect(r[m, 0], r[m, 1], w, h)
        p = canvas.panel(cell(0), xlim, ylim, margins=MARGINS)
        p.dots(r[keep, 0], r[keep, 1], viridis(ba.point_view[keep] / max(n_views - 1, 1)), radius_px=2.0)
        if out.any():
            p.crosses(r[out, 0], r[out, 1], RED)
            p.legend("rejected", "cross", RED)
        p.finish(xlabel="du (px)", ylabel="dv (px)", title_px=12.5,
                 title=f"{d}: residuals (px), RMS {ba.stats[d]['rms_px']:.4f}\n"
                       f"colour: view 1 (purple) to {n_views} (yellow)")
        rms = np.array([v[d]["rms_px"] or 0.0 for v in ba.stats["views"]])
        p = canvas.panel(cell(1), (0.5, n_views + 0.5), (0.0, 1.05 * max(float(rms.max()), 1e-12)), margins=MARGINS)
        p.stairs(rms, np.arange(n_views + 1) + 0.5, C0)
        p.finish(xlabel="view", ylabel="RMS residual (px)", title=f"{d}: per-view RMS")
        if sigma_pt is None:
            from ..calibrate import sigma_of_points

            sigma_pt = sigma_of_points(obs, ba)
        z, kept = distribution(cal, obs, d, sigma_pt)
        top = max(float(z.max()), (cal.outlier_threshold or 0) + 1)
        bins = np.linspace(0, top, 40)
        p = canvas.panel(cell(2), (-0.03 * top, 1.03 * top), (0.5, 2.0 * len(z)), ylog=True, margins=MARGINS)
        p.stairs(np.maximum(np.histogram(z[kept], bins)[0], 1e-3), bins, C0, baseline=1e-3)
        p.legend("kept", "patch", C0)
        if (~kept).any():
            p.stairs(np.maximum(np.histogram(z[~kept], bins)[0], 1e-3), bins, RED, baseline=1e-3)
            p.legend("rejected", "patch", RED)
        x = np.linspace(0, top, 200)
        p.line(x, len(z) * (bins[1] - bins[0]) * x * np.exp(-x * x / 2), BLACK)
        p.legend("Gaussian (Rayleigh)", "line", BLACK)
        if cal.outlier_threshold is not None:
            p.vline(cal.outlier_threshold, RED)
        p.finish(xlabel="|residual| / robust sigma", ylabel="points", title=f"{d}: residual distribution",
                 xticks=6, legend_loc="upper left")
    path = Path(path)
    with atomic_path(path) as tmp:
        canvas.image().quantize(PNG_COLOURS, method=Image.Quantize.FASTOCTREE).save(
            tmp, format="PNG", compress_level=PNG_COMPRESS_LEVEL)
    return path

