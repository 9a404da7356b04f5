"""unwrap.previews: the OpenCV previews of `calib unwrap` (colour scale, invalid pixels, size)."""
import math

import cv2
import numpy as np

from unwrap.pipeline import OrientationResult
from unwrap.previews import PANEL_WIDTH, colour_panel, preview_image, write_previews
from unwrap.temporal import Unwrapped


def test_colour_panel_scales_linearly_blacks_out_invalid_pixels_and_shrinks_wide_maps():
    img = np.tile(np.linspace(-2.0, 6.0, 9), (3, 1))
    img[1, 4] = np.nan
    bgr, lo, hi = colour_panel(img, None)
    assert (lo, hi) == (-2.0, 6.0) and bgr.shape == (3, 9, 3)
    assert bgr[0, 0].tolist() == [0, 0, 0] and bgr[0, -1].tolist() == [255, 255, 255]
    assert bgr[0, 4].tolist() == [127, 127, 127]          # the middle value, (255 / 2) truncated
    assert bgr[1, 4].tolist() == [0, 0, 0]                # NaN: black
    wide, _, _ = colour_panel(np.random.default_rng(0).random((100, 3 * PANEL_WIDTH)), cv2.COLORMAP_TURBO)
    assert wide.shape == (33, PANEL_WIDTH, 3)               # aspect kept: 100 * 400 / 1200 = 33.3 -> 33
    empty, lo, hi = colour_panel(np.full((4, 4), np.nan), cv2.COLORMAP_VIRIDIS)
    assert (lo, hi) == (0.0, 1.0) and not empty.any()


def _result(H=60, W=80):
    x = np.tile(np.arange(W, dtype=np.float64), (H, 1))
    f = 4.0
    phase = 2 * math.pi * f * x / W
    valid = np.ones((H, W), bool)
    valid[:10, :10] = False
    order = np.where(valid, np.floor(phase / (2 * math.pi)).astype(np.int32), -1)
    u = Unwrapped(np.where(valid, phase, np.nan), order, valid, phase / (2 * math.pi), f, "mf")
    return OrientationResult("v", float(W), u, np.where(valid, 50.0, 0.0), np.full((H, W), 100.0))


def test_preview_has_three_panels_with_titles_and_writes_a_png(tmp_path):
    r = _result()
    img = preview_image("v", r)
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
    assert img.shape[1] == 3 * 80 + 2 * 6 and img.shape[0] == 22 + 60 + 20
    body = img[22:82]
    for k in range(3):                                     # each panel: the invalid corner is black
        panel = body[:, k * 86:k * 86 + 80]
        assert not panel[:10, :10].any() and panel[30:, 40:].any()
    assert body[:, 80:86].min() == 255                     # white gap between the panels
    paths = write_previews({"v": r, "h": r}, tmp_path)
    assert [p.name for p in paths] == ["v_unwrap.png", "h_unwrap.png"]
    back = cv2.imread(str(paths[0]), cv2.IMREAD_UNCHANGED)
    assert back.shape == img.shape and np.array_equal(back, img)
