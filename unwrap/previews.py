"""PNG previews of decoded orientations, drawn with OpenCV (no matplotlib).

One image per orientation, ``OUT/{o}_unwrap.png``: three panels side by side (projector
coordinate in px, viridis; fringe order k, turbo; modulation B in grey levels, grey), each
scaled to at most :data:`PANEL_WIDTH` px wide, invalid pixels black, a title line above each
panel with its value range (the colour scale runs linearly from the low to the high value), and
a footer with the method and the valid share. Previews are for a glance; the numbers are in
``unwrap.h5``.

Why not matplotlib: importing pyplot and drawing two 3-panel figures with colour bars cost
~1.5-2.3 s of a ~3.6 s ``calib unwrap`` on a 900 x 700 capture (docs/speed.md, session 7,
branch unwrapcmd); this costs a few tens of ms.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .patterns import projector_coordinate
from .safe_output import write_bytes

PANEL_WIDTH = 400
"""Largest panel width in px (a panel is shrunk by area averaging, never enlarged)."""

_TITLE_H, _FOOT_H, _GAP = 22, 20, 6


def colour_panel(img, colormap: int | None, width: int = PANEL_WIDTH):
    """``img`` (H, W) real, NaN = invalid -> ((h, w, 3) uint8 BGR, lo, hi): linear from the finite
    minimum ``lo`` to maximum ``hi`` (0 and 1 when there is none), OpenCV ``colormap`` (None:
    grey), invalid pixels black, shrunk to at most ``width`` px wide."""
    import cv2

    a = np.asarray(img, dtype=np.float32)
    ok = np.isfinite(a)
    lo, hi = (float(a[ok].min()), float(a[ok].max())) if ok.any() else (0.0, 1.0)
    scale = 255.0 / (hi - lo) if hi > lo else 0.0
    u8 = np.clip((np.where(ok, a, lo) - lo) * scale, 0, 255).astype(np.uint8)
    bgr = cv2.cvtColor(u8, cv2.COLOR_GRAY2BGR) if colormap is None else cv2.applyColorMap(u8, colormap)
    bgr[~ok] = 0
    if bgr.shape[1] > width:
        h = max(1, round(bgr.shape[0] * width / bgr.shape[1]))
        bgr = cv2.resize(bgr, (width, h), interpolation=cv2.INTER_AREA)
    return bgr, lo, hi


def preview_image(o: str, r) -> np.ndarray:
    """The (H, W, 3) uint8 BGR preview of one :class:`unwrap.pipeline.OrientationResult` ``r`` of
    orientation ``o`` (module docstring)."""
    import cv2

    u = r.result
    # each panel's map made when drawn (one map-sized temporary at a time: the previews are drawn
    # beside the unwrap.h5 write); the orders in float32 directly (exact), as colour_panel reads them
    panels = [(lambda: projector_coordinate(np.asarray(u.phase), u.frequency, r.width), cv2.COLORMAP_VIRIDIS,
               f"projector coordinate ({o}) px"),
              (lambda: np.where(u.valid, np.asarray(u.order).astype(np.float32), np.float32(np.nan)),
               cv2.COLORMAP_TURBO, f"fringe order k (f = {u.frequency:g})"),
              (lambda: r.modulation, None, "modulation B")]
    drawn = []
    for img, cmap, title in panels:
        bgr, lo, hi = colour_panel(img(), cmap)
        top = np.full((_TITLE_H, bgr.shape[1], 3), 255, np.uint8)
        cv2.putText(top, f"{title} [{lo:.4g}, {hi:.4g}]", (3, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1,
                    cv2.LINE_AA)
        drawn.append(np.vstack([top, bgr]))
    h = max(p.shape[0] for p in drawn)
    row = []
    for p in drawn:
        row += [np.pad(p, ((0, h - p.shape[0]), (0, 0), (0, 0)), constant_values=255),
                np.full((h, _GAP, 3), 255, np.uint8)]
    body = np.hstack(row[:-1])
    foot = np.full((_FOOT_H, body.shape[1], 3), 255, np.uint8)
    cv2.putText(foot, f"{o}: method {u.method}, valid {100 * np.mean(u.valid):.1f} %", (3, 14),
                cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([body, foot])


def encode_previews(results: dict) -> dict:
    """``{orientation: PNG bytes}`` of every orientation of ``results`` ({o: OrientationResult})."""
    import cv2

    out = {}
    for o, r in results.items():
        ok, png = cv2.imencode(".png", preview_image(o, r))
        if not ok:
            raise OSError(f"cannot encode the preview of orientation {o}")
        out[o] = png.tobytes()
    return out


def write_previews(results: dict, out: Path, encoded: dict | None = None) -> list:
    """Write ``out/{o}_unwrap.png`` for every orientation of ``results`` ({o: OrientationResult}),
    atomically (:func:`unwrap.safe_output.write_bytes`); returns the paths. ``encoded``: the
    :func:`encode_previews` of ``results`` when already made (drawn beside the ``unwrap.h5`` write)."""
    encoded = encode_previews(results) if encoded is None else encoded
    return [write_bytes(Path(out) / f"{o}_unwrap.png", encoded[o]) for o in results]
