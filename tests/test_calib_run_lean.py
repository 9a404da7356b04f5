"""`calib run` does what its solver needs and no more (issue 22): an observation-only run imports
neither the board detection nor matplotlib (its summary figure is drawn with Pillow) nor the
learning or optimisation libraries it does not use; the uncertainty model's Jacobian is the
adjustment's own (analytic), the same as central differences of an independent rebuild of the
model; the numpy NNLS is scipy's."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]

#: What an observation-only run must not import (cv2 is imported by the seeds: cv2.solvePnP).
NOT_NEEDED = ("calib.detect", "unwrap.pipeline", "scipy.spatial", "scipy.ndimage", "scipy.optimize", "scipy.special",
              "torch", "matplotlib.pyplot", "mrcal")

_PROBE = """
import json, sys
import numpy as np
from calib import default_system
from calib.board import Board
from calib.observations import write_observations_json
from calib.simulate import board_poses_world, simulate_observations
from sltwin.cli import main
obs, _ = simulate_observations(default_system().ideal(), Board("checkerboard", 6, 8, 20.0), 6, 0.05,
                               np.random.default_rng(5), poses=board_poses_world(6, np.random.default_rng(11)),
                               projector_from_camera=True, noise_prj_px=0.0125)
path = write_observations_json(obs, sys.argv[1] + "/obs.json")
rc = main(["run", "--observations", str(path), "-o", sys.argv[1] + "/out", "-q", "--distortion", "0",
           "--figures", sys.argv[2]])
print(json.dumps({"rc": rc, "modules": sorted(sys.modules)}))
"""


def _run(tmp_path, figures):
    p = subprocess.run([sys.executable, "-c", _PROBE, str(tmp_path), figures], capture_output=True, text=True,
                       cwd=REPO, env=dict(os.environ, PYTHONPATH=str(REPO)), timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    out = json.loads(p.stdout.strip().splitlines()[-1])
    assert out["rc"] == 0
    return set(out["modules"])


def test_an_observation_only_run_imports_only_what_its_stages_use(tmp_path):
    modules = _run(tmp_path, "none")
    assert "calib.adjustment.solver" in modules and "calib.uncertainty.pose_error_model" in modules   # it ran
    assert not [m for m in NOT_NEEDED + ("matplotlib", "importlib.metadata") if m in modules], sorted(modules)
    assert (tmp_path / "out" / "calibration.json").is_file() and not (tmp_path / "out" / "residuals.png").exists()


def test_the_default_run_draws_the_summary_figure_without_matplotlib(tmp_path):
    modules = _run(tmp_path, "summary")
    assert "calib.io.summary_figure" in modules                  # drawn with Pillow (calib.io.raster_plot)
    assert not [m for m in NOT_NEEDED + ("matplotlib",) if m in modules], sorted(modules)
    out = tmp_path / "out"
    assert (out / "residuals.png").stat().st_size > 10_000
    assert not (out / "residuals_per_pose.png").exists() and not (out / "residuals_on_board.png").exists()


def test_the_per_pose_figures_are_drawn_without_matplotlib_too(tmp_path):
    modules = _run(tmp_path, "all")
    assert "calib.uncertainty.diagnostic_figures" in modules
    assert not [m for m in NOT_NEEDED + ("matplotlib",) if m in modules], sorted(modules)
    out = tmp_path / "out"
    assert all((out / n).stat().st_size > 10_000 for n in ("residuals.png", "residuals_per_pose.png",
                                                             "residuals_on_board.png"))


def test_the_analytic_jacobian_is_the_central_differences_one():
    """The adjustment's kernel (exact derivatives) against central differences of the independent
    DeviceModel rebuild: the columns agree to the differences' rounding (~1e-7 of a column's
    largest entry), the sigmas of the error model to 1e-6 (measured 5e-7 on the paper's views; the
    differences move by 1e-5 when their step is 10x smaller, 3e-8 when 10x larger: theirs is the
    rounding error)."""
    from calib.adjustment.jacobian import adjustment_jacobian
    from calib.calibrate import run_calibration
    from calib.uncertainty.pose_error_model import fit_pose_error_model
    from tests.test_uncertainty import CONFIG, session

    obs = session(2, shift_cam_px=0.1, shift_prj_px=0.3)
    cal = run_calibration(obs, CONFIG)
    a = adjustment_jacobian(cal, obs)
    d = adjustment_jacobian(cal, obs, method="differences")
    assert a.names == d.names and a.J.shape == d.J.shape
    Ja, Jd = a.J.toarray(), d.J.toarray()
    assert np.all(np.abs(Ja - Jd).max(axis=0) <= 1e-5 * np.abs(Jd).max(axis=0)), np.abs(Ja - Jd).max(axis=0)
    np.testing.assert_allclose(a.r, d.r, rtol=0, atol=1e-10 * np.abs(d.r).max())
    ea, ed = fit_pose_error_model(a, obs), fit_pose_error_model(d, obs)
    kept_a = {k for k, v in ea.fields.items() if v > 0}
    assert kept_a == {k for k, v in ed.fields.items() if v > 0} and kept_a        # the same shared errors found
    # measured 3.5e-7 apart: the central differences' rounding (docs/speed.md), not the analytic Jacobian's
    for n in ed.std:
        assert ea.std[n] == pytest.approx(ed.std[n], rel=1e-5), n
        assert ea.std_independent[n] == pytest.approx(ed.std_independent[n], rel=1e-5), n


def test_numpy_nnls_is_scipys():
    import scipy.optimize

    from calib.uncertainty.nnls import nnls

    rng = np.random.default_rng(1)
    for _ in range(300):
        m, n = rng.integers(3, 20), rng.integers(1, 14)
        A = rng.normal(size=(m, n)) * 10.0 ** rng.uniform(-2, 2, size=n)
        b = rng.normal(size=m)
        x, rnorm = nnls(A, b)
        want, wnorm = scipy.optimize.nnls(A, b)
        assert np.all(x >= 0) and rnorm <= wnorm + 1e-9 * np.linalg.norm(b)
        if m > n:                       # full column rank: one solution
            np.testing.assert_allclose(x, want, rtol=0, atol=1e-8 * max(np.abs(want).max(), 1e-12))


def test_numpy_nnls_is_exactly_feasible_on_ill_scaled_systems():
    """Solutions up to 1e10 and columns over six decades: the step to the boundary rounds, and a
    variable leaving the passive set is set to exactly 0 (Lawson-Hanson), so x >= 0 holds exactly
    (no -1e-17), the residual is that of x, and x is scipy's to rounding (full column rank)."""
    import scipy.optimize

    from calib.uncertainty.nnls import nnls

    rng = np.random.default_rng(0)
    bound = 0
    for _ in range(1500):
        m, n = rng.integers(3, 20), rng.integers(2, 14)
        A = rng.normal(size=(m, n)) * 10.0 ** rng.uniform(-3, 3, size=n)
        b = rng.normal(size=m) * 10.0 ** rng.uniform(-3, 8)
        x, rnorm = nnls(A, b)
        assert np.all(x >= 0.0) and rnorm == np.linalg.norm(A @ x - b)
        bound += int(np.any(x == 0.0))
        if m > n:
            want, wnorm = scipy.optimize.nnls(A, b)
            assert rnorm <= wnorm * (1 + 1e-9) + 1e-12 * np.linalg.norm(b)
            np.testing.assert_allclose(x, want, rtol=0, atol=1e-9 * max(np.abs(want).max(), 1e-300))
    assert bound > 500              # the constraint binds in most systems: the inner loop ran
