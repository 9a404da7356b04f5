"""The per-pose figures of `calib run --figures all` drawn with Pillow
(calib/uncertainty/diagnostic_figures.py, issue 22): valid PNGs, one panel per device and view;
arrows run from the point along the residual in the panel's own axes (an image's rows down)."""
import numpy as np
import pytest
from PIL import Image

from calib.io import raster_plot as RP
from calib.uncertainty.diagnostic_figures import BOARD_CELL, POSE_CELL, POSE_TOP
from calib.uncertainty.diagnostics import plot_residual_diagnostics
from tests.test_summary_figure import run  # noqa: F401  (the fixture: 6 simulated views, one outlier)


def test_both_figures_are_pngs_with_a_panel_per_device_and_view(run, tmp_path):
    cal, obs = run.calibration, run.observations
    paths = plot_residual_diagnostics(cal, obs, cal.uncertainty.diagnostics, tmp_path)
    assert sorted(paths) == ["residuals_on_board.png", "residuals_per_pose.png"]
    sizes = {}
    for name, path in paths.items():
        with Image.open(path) as im:
            im.verify()
        with Image.open(path) as im:
            sizes[name] = im.size
    n = len(obs.views)
    assert sizes["residuals_per_pose.png"] == (POSE_CELL[0] * n, 2 * POSE_CELL[1] + POSE_TOP)
    assert sizes["residuals_on_board.png"] == (3 * BOARD_CELL[0], BOARD_CELL[1])
    a = np.asarray(Image.open(paths["residuals_per_pose.png"]).convert("RGB")).reshape(-1, 3)
    assert (np.abs(a.astype(int) - RP.C0).max(axis=1) <= 8).sum() > 50 * n            # the arrows are there
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(paths)


def test_an_arrow_points_along_its_vector_on_an_image_axis():
    c = RP.Canvas(100, 100)
    p = c.panel((0, 0, 100, 100), xlim=(0, 100), ylim=(100, 0), margins=(0, 0, 0, 0))    # rows down
    p.arrows([50.0], [20.0], [0.0], [60.0], (255, 0, 0), width_px=1.0, head_px=5.0)
    a = np.asarray(p.im)
    rows = np.flatnonzero((a == (255, 0, 0)).all(axis=2).any(axis=1)) / c.s
    assert rows.min() == pytest.approx(20, abs=1.5) and rows.max() == pytest.approx(80, abs=1.5)
    head = (a == (255, 0, 0)).all(axis=2)
    widths = head.sum(axis=1)
    assert widths[round(77 * c.s)] > widths[round(40 * c.s)]        # the head is at the end
