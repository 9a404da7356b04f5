"""The per-pose residual figures of ``calib run --figures all``, drawn with Pillow
(:mod:`calib.io.raster_plot`) like the summary figure, not matplotlib:

- ``residuals_per_pose.png``: one panel per device and view, the device's whole image (equal
  aspect, rows down), residual vectors magnified at the observed pixels, rejected points as red
  crosses; titles with the view's RMS and its rejections;
- ``residuals_on_board.png``: per device the residual vectors at the board points, one colour per
  view (matplotlib's cycle), rejected points as red crosses, the neighbour correlation in the
  title; then the correlogram (residual correlation within a pose against distance on the board,
  log distance, 0 marked).

Pixel sizes follow the matplotlib figures they replace (90 dpi: 3.2 x 2.9 in per pose panel,
4.6 x 4.2 in per board panel).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from unwrap.safe_output import atomic_path

from ..io.raster_plot import C0, CYCLE, RED, Canvas

#: A pose panel's cell and a board panel's cell, final pixels.
POSE_CELL, BOARD_CELL = (288, 261), (414, 378)
#: The suptitle's band above the pose panels, final pixels.
POSE_TOP = 40
GREY_LINE = (128, 128, 128)


def save_png(canvas: Canvas, path) -> Path:
    """``canvas`` to ``path`` atomically: a 256-colour palette PNG at zlib level 1 (as
    :mod:`calib.io.summary_figure`)."""
    from ..io.summary_figure import PNG_COLOURS, PNG_COMPRESS_LEVEL

    path = Path(path)
    with atomic_path(path) as tmp:
        canvas.image().quantize(PNG_COLOURS, method=Image.Quantize.FASTOCTREE).save(
            tmp, format="PNG", compress_level=PNG_COMPRESS_LEVEL)
    return path


def _pose_points(obs, d, v, ids_m):
    """Observed pixels (K, 2) of device ``d`` in view ``v`` at the point ids ``ids_m`` (the
    adjustment's point order)."""
    view = obs.views[v]
    order = np.argsort(view.ids, kind="stable")
    at = order[np.searchsorted(view.ids, ids_m, sorter=order)]
    return np.asarray(view.q[d], dtype=float)[at].reshape(-1, 2)


def per_pose_figure(cal, obs, devices, points, path) -> Path:
    """``residuals_per_pose.png`` (module docstring). ``points``: {device: (views, xy, res, ok)} of
    :func:`calib.uncertainty.diagnostics._points`."""
    ba = cal.ba
    n = len(obs.views)
    cw, ch = POSE_CELL
    canvas = Canvas(cw * n, ch * len(devices) + POSE_TOP)
    scales = []
    for row, d in enumerate(devices):
        views, _, res, ok = points[d]
        q_all = np.concatenate([obs.views[v].q[d][obs.views[v].seen(d)] for v in range(n) if d in obs.views[v].q])
        scale = 0.05 * max(np.ptp(q_all[:, 0]), 1.0) / max(np.sqrt(np.mean(res[ok] ** 2)), 1e-12)
        scales.append(scale)
        W, H = obs.sizes[d]
        ids_d = ba.point_id[ba.point_device == d]
        for v in range(n):
            m = views == v
            q = _pose_points(obs, d, v, ids_d[m])
            good = ok[m]
            p = canvas.panel((v * cw, POSE_TOP + row * ch, cw, ch), (0, W), (H, 0), margins=(10, 10, 34, 12),
                             equal=True)
            # along the residual in the image (rows down); matplotlib's quiver drew -dv here: mirrored
            p.arrows(q[good, 0], q[good, 1], scale * res[m][good, 0], scale * res[m][good, 1], C0, width_px=1.0,
                     head_px=4.0)
            p.crosses(q[~good, 0], q[~good, 1], RED, size_px=4.5)
            rms = np.sqrt(np.mean(res[m][good] ** 2)) if good.any() else np.nan
            p.finish(title=f"{d} {obs.views[v].name}\nRMS {rms:.3f} px, {int((~good).sum())} rejected",
                     xticks=0, yticks=0, title_px=8.75)
    canvas.text((canvas.size[0] * canvas.s / 2, 12 * canvas.s),
                "residual vectors (" + ", ".join(f"{d} x {sc:.0f}" for d, sc in zip(devices, scales))
                + ") at the observed pixels (each panel: the whole image); red x: rejected", 11.25, anchor="mt")
    return save_png(canvas, path)


def board_figure(cal, obs, devices, points, diagnostics, path) -> Path:
    """``residuals_on_board.png`` (module docstring)."""
    cw, ch = BOARD_CELL
    canvas = Canvas(cw * (len(devices) + 1), ch)
    margins = (60, 14, 48, 48)
    for k, d in enumerate(devices):
        views, xy, res, ok = points[d]
        scale = 0.04 * max(np.ptp(xy[:, 0]), 1.0) / max(np.sqrt(np.mean(res[ok] ** 2)), 1e-12)
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        pad = 0.05 * np.maximum(hi - lo, 1e-9)
        p = canvas.panel((k * cw, 0, cw, ch), (lo[0] - pad[0], hi[0] + pad[0]), (lo[1] - pad[1], hi[1] + pad[1]),
                         margins=margins, equal=True)
        for v in np.unique(views):
            m = (views == v) & ok
            colour = CYCLE[int(v) % len(CYCLE)]
            # residuals in image rows (down) drawn on the board's y (up): dv flipped, as before
            p.arrows(xy[m, 0], xy[m, 1], scale * res[m, 0], -scale * res[m, 1], colour, width_px=1.0, head_px=4.0)
            p.legend(obs.views[int(v)].name, "patch", colour)
        p.crosses(xy[~ok, 0], xy[~ok, 1], RED, size_px=5.5)
        p.legend("rejected", "cross", RED)
        rho = diagnostics.neighbour_correlation.get(d)
        p.finish(xlabel="board x (mm)", ylabel="board y (mm)", font_px=12.5, title_px=10.0, legend_px=6.25,
                 title=f"{d}: residuals on the board (x {scale:.0f})\nneighbour correlation "
                       f"{'n/a' if rho is None else f'{rho:.2f}'}")
    curves = {d: np.array(diagnostics.correlogram.get(d, [])).reshape(-1, 3) for d in devices}
    g = np.concatenate([c for c in curves.values() if len(c)] or [np.array([[1.0, 0.0, 0], [10.0, 0.0, 0]])])
    x0, x1 = float(g[:, 0].min()), float(g[:, 0].max())
    span = np.log10(x1 / x0) if x1 > x0 > 0 else 1.0
    xlim = (x0 / 10 ** (0.05 * span), x1 * 10 ** (0.05 * span))
    y0, y1 = min(float(g[:, 1].min()), 0.0), max(float(g[:, 1].max()), 0.0)
    ylim = (y0 - 0.05 * (y1 - y0 or 1), y1 + 0.05 * (y1 - y0 or 1))
    p = canvas.panel((len(devices) * cw, 0, cw, ch), xlim, ylim, xlog=True, margins=(75, 14, 48, 48))
    p.hline(0.0, GREY_LINE, width_px=0.8)
    for k, d in enumerate(devices):
        c = curves[d]
        if len(c):
            p.line(c[:, 0], c[:, 1], CYCLE[k], width_px=1.5)
            p.dots(c[:, 0], c[:, 1], CYCLE[k], radius_px=3.0)
            p.legend(d, "line", CYCLE[k])
    p.finish(xlabel="distance on the board (mm)", ylabel="residual correlation within a pose", title_px=10.0,
             title="correlogram (independent errors: 0)", legend_loc="upper left", legend_px=8.75, plain_log=True)
    return save_png(canvas, path)

