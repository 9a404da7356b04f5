"""`calib run`'s summary figure drawn with Pillow (calib/io/summary_figure.py over
calib/io/raster_plot.py, issue 22): a valid PNG of one column per device and three panels each;
the data land where the axes say (dots at their data coordinates, later ones on top, clipped to
the panel, a log axis by decades); ticks at 1-2-2.5-5 steps; viridis as matplotlib's; drawing it
leaves the calibration as it was."""
import numpy as np
import pytest
from PIL import Image

from calib import default_system
from calib.board import Board
from calib.io import raster_plot as RP
from calib.io.summary_figure import CELL_H, CELL_W, distribution, summary_figure
from calib.pipeline import calibrate_observations
from calib.simulate import board_poses_world, simulate_observations


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    obs, _ = simulate_observations(default_system().ideal(), Board("checkerboard", 6, 8, 20.0), 6, 0.05,
                                   np.random.default_rng(5), poses=board_poses_world(6, np.random.default_rng(11)),
                                   projector_from_camera=True, noise_prj_px=0.0125)
    obs.views[2].q["camera"][5] += 3.0          # one gross outlier: rejected, drawn as a red cross
    return calibrate_observations(obs, tmp_path_factory.mktemp("out"), figures="none", skew_check=False)


def _colours(path):
    a = np.asarray(Image.open(path).convert("RGB")).reshape(-1, 3)
    return {tuple(c) for c in np.unique(a, axis=0)}


def _near(colours, want, tol=8):
    return any(max(abs(int(a) - int(b)) for a, b in zip(c, want)) <= tol for c in colours)


def test_the_summary_figure_is_a_png_with_every_panel_and_leaves_the_calibration(run, tmp_path):
    cal, obs = run.calibration, run.observations
    assert any(r["device"] == "camera" for r in cal.ba.rejected)
    before = (cal.system.camera.K.copy(), cal.system.projector.K.copy(), cal.ba.residuals_px.copy())
    path = summary_figure(cal, obs, tmp_path / "residuals.png")
    with Image.open(path) as im:
        im.verify()
    with Image.open(path) as im:
        assert im.format == "PNG" and im.size == (2 * CELL_W, 3 * CELL_H)
    colours = _colours(path)
    for want in (RP.viridis(0.0), RP.viridis(1.0), RP.C0, RP.RED, RP.BLACK):     # views 1 and 6, bars, rejected
        assert _near(colours, tuple(want)), want
    np.testing.assert_array_equal(cal.system.camera.K, before[0])
    np.testing.assert_array_equal(cal.system.projector.K, before[1])
    np.testing.assert_array_equal(cal.ba.residuals_px, before[2])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["residuals.png"]       # no temporary file left


def test_the_distribution_is_normalised_by_the_kept_points_robust_sigma(run):
    cal, obs = run.calibration, run.observations
    z, kept = distribution(cal, obs, "projector")
    # Rayleigh: the median of z^2 over the kept points is 2 ln 2 by construction
    assert np.median(z[kept] ** 2) == pytest.approx(2 * np.log(2), rel=1e-12)
    z, kept = distribution(cal, obs, "camera")
    assert (~kept).sum() >= 1 and z[~kept].max() > cal.outlier_threshold


def test_dots_land_at_their_data_coordinates_the_last_on_top_clipped_to_the_panel():
    c = RP.Canvas(200, 200)
    p = c.panel((0, 0, 200, 200), xlim=(0, 10), ylim=(0, 10), margins=(0, 0, 0, 0))
    red, blue = (255, 0, 0), (0, 0, 255)
    p.dots([2.5, 2.5, 7.5, 20.0], [7.5, 7.5, 2.5, 5.0], np.array([red, blue, red, blue], np.uint8), radius_px=3)
    a = np.asarray(p.im)
    s = c.s
    assert tuple(a[round(0.25 * 200 * s), round(0.25 * 200 * s)]) == blue    # (2.5, 7.5): top left, the later dot
    assert tuple(a[round(0.75 * 200 * s), round(0.75 * 200 * s)]) == red     # (7.5, 2.5): bottom right
    assert (a == blue).all(axis=2).sum() == (a == red).all(axis=2).sum()     # x = 20 is outside: not drawn
    assert tuple(a[0, 0]) == (255, 255, 255)


def test_a_log_axis_maps_decades_evenly_and_labels_them():
    c = RP.Canvas(100, 100)
    p = c.panel((0, 0, 100, 100), xlim=(0, 1), ylim=(1, 1000), ylog=True, margins=(0, 0, 0, 0))
    _, v = p.px([0, 0, 0, 0], [1, 10, 100, 1000])
    np.testing.assert_allclose(np.diff(v), -p.h / 3)
    assert [t for _, t in p._ticks(1, 1000, 5, True)] == ["10\u2070", "10\u00b9", "10\u00b2", "10\u00b3"]
    _, v = p.px([0], [0.0])        # a log axis' zero: below the panel, not NaN
    assert v[0] > p.h


@pytest.mark.parametrize("lo, hi, want, decimals", [
    (0.0, 1.0, [0.0, 0.2, 0.4, 0.6, 0.8, 1.0], 1),
    (-0.33, 0.21, [-0.3, -0.2, -0.1, 0.0, 0.1, 0.2], 1),
    (0.5, 100.5, [20.0, 40.0, 60.0, 80.0, 100.0], 0),
    (0.0, 0.125, [0.0, 0.025, 0.05, 0.075, 0.1, 0.125], 3),
    (-1.3, 1.3, [-1.0, -0.5, 0.0, 0.5, 1.0], 1),
])
def test_nice_ticks(lo, hi, want, decimals):
    ticks, d = RP.nice_ticks(lo, hi)
    np.testing.assert_allclose(ticks, want, atol=1e-12)
    assert d == decimals
    assert RP.tick_label(-0.0001, 1) == "0" and RP.tick_label(-0.2, 1) == "\u22120.2"


def test_viridis_is_matplotlibs():
    from matplotlib import colormaps

    t = np.linspace(0, 1, 257)
    want = colormaps["viridis"](t)[:, :3] * 255
    assert np.abs(RP.viridis(t).astype(float) - want).max() <= 6


def test_one_device_and_no_rejection_rule_draw_one_column(tmp_path):
    """Single-device mode, ``--outlier-threshold 0`` (no rule: no threshold line, no rejected points)."""
    from calib.adjustment.problem import BAConfig

    obs, _ = simulate_observations(default_system().ideal(), Board("checkerboard", 6, 8, 20.0), 5, 0.05,
                                   np.random.default_rng(2), poses=board_poses_world(5, np.random.default_rng(3)),
                                   projector_from_camera=True, noise_prj_px=0.0125)
    for v in obs.views:
        v.q.pop("projector", None)
    run = calibrate_observations(obs, tmp_path / "out", BAConfig(mode="single", outlier_threshold=None),
                                 skew_check=False, view_noise=False)
    assert run.calibration.outlier_threshold is None and not run.calibration.ba.rejected
    path = tmp_path / "out" / "residuals.png"
    with Image.open(path) as im:
        assert im.size == (CELL_W, 3 * CELL_H)
    assert not _near(_colours(path), RP.RED, tol=40)       # nothing rejected, no threshold drawn


def test_noise_free_residuals_draw_without_dividing_by_zero(run, tmp_path):
    from dataclasses import replace

    ba = run.calibration.ba
    cal = replace(run.calibration, ba=replace(ba, residuals_px=np.zeros_like(ba.residuals_px)))
    z, _ = distribution(cal, run.observations, "camera")
    assert np.all(z == 0)
    with Image.open(summary_figure(cal, run.observations, tmp_path / "residuals.png")) as im:
        assert im.size == (2 * CELL_W, 3 * CELL_H)
