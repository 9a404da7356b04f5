"""The uncertainty a calibration reports: the adjustment's Jacobian rebuilt (and checked against its
covariance), the per-pose error model (honest when a pose's observations share errors, equal to
the adjustment's when they do not), resampling over poses, and the residual diagnostics."""
import json

import numpy as np
import pytest

from calib import default_system
from calib.board import Board
from calib.adjustment.problem import BAConfig, DeviceConfig
from calib.calibrate import run_calibration
from calib.uncertainty.pose_error_model import fit_pose_error_model
from calib.uncertainty.resampling import system_parameters
from calib.uncertainty.diagnostics import diagnose_residuals
from calib.adjustment.jacobian import adjustment_jacobian
from calib.simulate import board_poses_world, simulate_observations

SYSTEM = default_system().ideal()
BOARD = Board("checkerboard", 6, 8, 20.0)
CONFIG = BAConfig(camera=DeviceConfig(0), projector=DeviceConfig(0), outlier_threshold=None, progress=lambda s: None)
POSES = board_poses_world(6, np.random.default_rng(11))


def session(seed, shift_cam_px=0.0, shift_prj_px=0.0, noise_px=0.05):
    """Six poses; every pose's camera and projector observations shifted by its own random offset."""
    rng = np.random.default_rng(seed)
    obs, _ = simulate_observations(SYSTEM, BOARD, 6, noise_px, rng, poses=POSES, projector_from_camera=True,
                                   noise_prj_px=noise_px / 4)
    for v in obs.views:
        v.q["camera"] = v.q["camera"] + rng.normal(0, shift_cam_px, 2)
        v.q["projector"] = v.q["projector"] + rng.normal(0, shift_prj_px, 2)
    return obs


def test_rebuilt_jacobian_reproduces_the_adjustments_covariance():
    obs = session(0)
    cal = run_calibration(obs, CONFIG)
    aj = adjustment_jacobian(cal, obs)                       # refuses when it would not (1 %)
    std = np.sqrt(np.diag(aj.covariance()))
    for k, n in enumerate(aj.names):
        assert std[k] == pytest.approx(cal.ba.std[n], rel=1e-3), n
    assert aj.J.shape == (2 * len(aj.inlier), len(cal.ba.free_names))


def test_without_shared_errors_the_error_model_reports_the_adjustments_sigmas():
    obs = session(1)
    cal = run_calibration(obs, CONFIG)
    em = fit_pose_error_model(adjustment_jacobian(cal, obs), obs)
    inflation = np.array(list(em.inflation().values()))
    assert np.all(inflation < 1.3) and np.median(inflation) < 1.1, em.inflation()
    assert em.independent_fraction > 0.9


@pytest.mark.slow
def test_per_pose_shifts_the_error_model_sees_and_the_adjustment_does_not():
    """30 sessions with per-pose offsets (camera 0.1 px, projector 0.3 px, as a drifting projector
    image leaves) over 0.05 px noise: the estimates' deviations over the error model's sigma have an
    RMS near 1, and the spread is several times what independent residuals predict."""
    R_true = SYSTEM.projector.R @ SYSTEM.camera.R.T
    est, model, independent = [], [], []
    for seed in range(30):
        obs = session(100 + seed, shift_cam_px=0.1, shift_prj_px=0.3)
        cal = run_calibration(obs, CONFIG)
        em = fit_pose_error_model(adjustment_jacobian(cal, obs), obs)
        p = system_parameters(cal, R_true)
        est.append([p[n] for n in em.names])
        model.append([em.std[n] for n in em.names])
        independent.append([em.std_independent[n] for n in em.names])
    spread = np.std(est, axis=0, ddof=1)
    ratio_model = spread / np.sqrt(np.mean(np.square(model), axis=0))
    ratio_independent = spread / np.sqrt(np.mean(np.square(independent), axis=0))
    z = (np.array(est) - np.mean(est, axis=0)) / np.array(model)
    rms_z = np.sqrt(np.sum(z ** 2, axis=0) / (len(est) - 1))
    print("spread / model sigma", np.round(ratio_model, 2), "spread / independent", np.round(ratio_independent, 2),
          "rms z", np.round(rms_z, 2))
    # the sigmas carry the few-pose inflation (calib.uncertainty.level_uncertainty), which makes E[z^2] = 1 for
    # z = shift / sigma: measured RMS z 0.58-1.28 (median 0.84), spread / RMS sigma 0.45-0.88
    assert 0.7 < np.median(rms_z) < 1.3 and np.all((rms_z > 0.5) & (rms_z < 1.8)), rms_z
    assert np.median(ratio_independent) > 1.8, ratio_independent


def test_rejected_points_that_cluster_are_flagged_and_scattered_ones_are_not():
    def corrupted(ids_per_view):
        obs = session(5)
        for v, ids in zip(obs.views, ids_per_view):
            v.q["projector"][ids] += 3.0
        cal = run_calibration(obs, BAConfig(camera=DeviceConfig(0), projector=DeviceConfig(0), progress=lambda s: None))
        return diagnose_residuals(cal, obs)

    corner = [i for i in range(48) if i % 8 < 3 and i // 8 < 2]            # 6 points at a corner of the board
    clustered = corrupted([corner, corner, [], [], [], []])
    c = clustered.rejected_clusters["projector"]
    assert c["n"] >= 12 and c["p"] < 0.01 and set(c["poses"]) >= {0, 1}
    assert any("rejected projector points cluster" in w for w in clustered.warnings), clustered.warnings
    rng = np.random.default_rng(3)
    scattered = corrupted([rng.choice(48, 2, replace=False).tolist() for _ in range(6)])
    assert scattered.rejected_clusters["projector"]["p"] > 0.01
    assert not any("cluster" in w for w in scattered.warnings)


def test_calib_run_reports_uncertainty_warp_resampling_and_residual_figures(tmp_path, capsys):
    from calib.observations import write_observations_json
    from sltwin.cli import main

    path = write_observations_json(session(7, shift_cam_px=0.1, shift_prj_px=0.3), tmp_path / "obs.json")
    out = tmp_path / "out"
    assert main(["run", "--observations", str(path), "-o", str(out), "--distortion", "0",
                 "--uncertainty", "jackknife", "--figures", "all"]) == 0
    text = capsys.readouterr()
    assert "uncertainty (1 sigma): reported = pose error model" in text.out and "jackknife" in text.out
    assert "board_warp.cx (mm)" in text.out                    # 6 views: the warp is estimated by default
    cal = json.loads((out / "calibration.json").read_text())
    u = cal["uncertainty"]
    assert u["reported"] == "pose error model" and u["resampled"]["runs"] == 6
    assert cal["uncertainties_1sigma"]["camera"]["fx"] > 2 * cal["uncertainties_1sigma_independent_residuals"]["camera"]["fx"]
    assert "per_pose_field_sd_px" in u["error_model"] and cal["covariance"]["model"] == "pose error model"
    for name in ("residuals_per_pose.png", "residuals_on_board.png"):
        assert (out / name).stat().st_size > 20_000
    assert main(["run", "--observations", str(path), "-o", str(tmp_path / "o2"), "--distortion", "0",
                 "--board-warp", "off", "-q"]) == 0
    assert "board_warp_mm" not in json.loads((tmp_path / "o2" / "calibration.json").read_text())


def _many_pose_session(n, seed):
    rng = np.random.default_rng(seed)
    obs, _ = simulate_observations(SYSTEM, BOARD, n, 0.05, rng, poses=board_poses_world(n, np.random.default_rng(11)),
                                   projector_from_camera=True, noise_prj_px=0.0125)
    for v in obs.views:
        v.q["projector"] = v.q["projector"] + rng.normal(0, 0.3, 2)
    return obs


def test_the_few_pose_inflation_grows_as_poses_shrink_and_vanishes_for_many():
    """calib.uncertainty.level_uncertainty: per-pose levels estimated from few poses inflate the sigmas (a
    Student-t effect): more for 4 poses than for 8, near 1 for 24; exactly 1 without shared errors.
    Measured (largest over the parameters): 4 poses 1.64, 8 poses 1.20, 24 poses 1.04."""
    from calib.uncertainty.level_uncertainty import MIN_DOF

    def worst(n, seed=0):
        obs = _many_pose_session(n, seed)
        em = fit_pose_error_model(adjustment_jacobian(run_calibration(obs, CONFIG), obs), obs)
        return float(np.max(em.levels.inflation)), float(np.min(em.levels.dof)), em

    few, dof_few, _ = worst(4)
    some, _, _ = worst(8)
    many, dof_many, em = worst(24)
    print("inflation 4 / 8 / 24 poses:", few, some, many, "dof", dof_few, dof_many)
    assert few > some > many >= 1.0
    assert few > 1.3 and many < 1.08
    assert dof_few < MIN_DOF < dof_many
    # the covariance carries it: std = the sandwich's sigma times the inflation
    assert all(em.std[n] >= 0.999 * em.std_independent[n] for n in em.names)
    obs = session(1)                                                    # no shared errors
    em0 = fit_pose_error_model(adjustment_jacobian(run_calibration(obs, CONFIG), obs), obs)
    assert np.all(em0.levels.inflation == 1.0) and not em0.levels.field_dof


def test_a_small_session_with_shared_errors_says_its_sigmas_are_not_to_be_trusted():
    from calib.uncertainty.assess import assess_uncertainty

    obs = _many_pose_session(4, 3)
    report = assess_uncertainty(run_calibration(obs, CONFIG), obs)
    assert report.too_small and any("too small to trust its own sigmas" in w for w in report.warnings)
    d = report.to_dict()
    assert d["too_small_to_trust_sigmas"] is True and d["error_model"]["few_poses"]["sigma_inflation"]
    obs = _many_pose_session(16, 3)
    assert not assess_uncertainty(run_calibration(obs, CONFIG), obs).too_small


def test_point_ids_are_the_loop_over_views_on_a_random_layout():
    """calib.adjustment.jacobian._point_ids (one gather over every view's ids) gives what a loop
    over the views gives, for views of different sizes, unsorted ids, points in any order."""
    from types import SimpleNamespace

    from calib.adjustment.jacobian import _point_ids

    rng = np.random.default_rng(4)
    views = [SimpleNamespace(ids=rng.permutation(200)[:rng.integers(0, 60)]) for _ in range(9)]
    sized = [i for i, v in enumerate(views) if len(v.ids)]
    view = rng.choice(sized, size=500)
    index = np.array([rng.integers(len(views[i].ids)) for i in view])
    loop = np.empty(len(view), dtype=np.int64)
    for i, v in enumerate(views):
        loop[view == i] = v.ids[index[view == i]]
    got = _point_ids(SimpleNamespace(views=views), view, index)
    assert got.dtype == np.int64 and np.array_equal(got, loop)
    assert _point_ids(SimpleNamespace(views=views), np.zeros(0, int), np.zeros(0, int)).shape == (0,)
