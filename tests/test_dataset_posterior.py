"""Systems drawn from a calibration's posterior (synth.export.posterior; export ``perturb = "posterior"``)."""
import json
from types import SimpleNamespace

import numpy as np
import pytest

from calib import default_system
from calib.io.outputs import covariance_of_system
from calib.io.calibration_json import system_to_dict
from synth.errors import SynthError
from synth.export.posterior import PosteriorSampler


def _write(tmp_path, names, cov):
    d = system_to_dict(default_system(), covariance={"names": names, "matrix": np.asarray(cov).tolist()})
    p = tmp_path / "calibration.json"
    p.write_text(json.dumps(d))
    return p


def test_calib_run_covariance_keeps_intrinsics_and_rig_and_drops_board_poses():
    names = ["camera.fx", "cam_board/0.w0", "prj_cam.t2", "board_warp.cx"]
    cov = np.diag([1.0, 2.0, 3.0, 4.0])
    out = covariance_of_system(SimpleNamespace(ba=SimpleNamespace(free_names=names, cov=cov)))
    assert out["names"] == ["camera.fx", "prj_cam.t2"] and out["matrix"] == [[1.0, 0.0], [0.0, 3.0]]


def test_draws_follow_the_covariance_and_move_the_projector_with_the_rig(tmp_path):
    base = default_system()
    names = ["camera.fx", "camera.k1", "projector.cy", "prj_cam.w1", "prj_cam.t0"]
    std = np.array([0.5, 1e-3, 0.3, 1e-4, 0.05])
    corr = np.eye(5)
    corr[0, 1] = corr[1, 0] = 0.9
    sampler = PosteriorSampler(base, _write(tmp_path, names, corr * np.outer(std, std)))
    rng = np.random.default_rng(0)
    draws = [sampler(rng) for _ in range(3000)]
    fx = np.array([s.camera.fx for s in draws]) - base.camera.fx
    k1 = np.array([s.camera.distortion[0] for s in draws]) - base.camera.distortion[0]
    cy = np.array([s.projector.cy for s in draws]) - base.projector.cy
    assert abs(fx.std() / 0.5 - 1) < 0.05 and abs(cy.std() / 0.3 - 1) < 0.05
    assert abs(np.corrcoef(fx, k1)[0, 1] - 0.9) < 0.03
    s = draws[0]
    np.testing.assert_allclose(s.camera.R, base.camera.R)
    np.testing.assert_allclose(s.camera.t, base.camera.t)
    # the rig (projector relative to camera) moved by the drawn increments, the projector follows
    R_pc0 = base.projector.R @ base.camera.R.T
    R_pc = s.projector.R @ s.camera.R.T
    assert 0 < np.linalg.norm(R_pc - R_pc0) < 1e-2
    np.testing.assert_allclose(s.projector.R @ s.projector.R.T, np.eye(3), atol=1e-12)


def test_zero_covariance_returns_the_system_and_missing_covariance_is_refused(tmp_path):
    base = default_system()
    s = PosteriorSampler(base, _write(tmp_path, ["camera.fx"], [[0.0]]))(np.random.default_rng(1))
    np.testing.assert_allclose(s.camera.K, base.camera.K)
    np.testing.assert_allclose(s.projector.t, base.projector.t, atol=1e-12)
    p = tmp_path / "plain.json"
    p.write_text(json.dumps(system_to_dict(base)))
    with pytest.raises(SynthError, match="has no 'covariance'"):
        PosteriorSampler(base, p)
    with pytest.raises(SynthError, match="not positive semi-definite"):
        PosteriorSampler(base, _write(tmp_path, ["camera.fx", "camera.fy"], [[1.0, 2.0], [2.0, 1.0]]))


def test_posterior_export_draws_one_system_per_sample_and_stays_deterministic(tmp_path):
    from synth.export.dataset import export_dataset

    from dataset_helpers import arrays_of, assert_same_arrays, tiny_config

    cfg = tiny_config(tmp_path, samples=2)
    d = json.loads((tmp_path / "system.json").read_text())
    d["covariance"] = {"names": ["camera.fx", "prj_cam.t0"], "matrix": [[4.0, 0.0], [0.0, 0.25]]}
    (tmp_path / "system.json").write_text(json.dumps(d))
    cfg.write_text(cfg.read_text().replace('file = "system.json"', 'file = "system.json"\nperturb = "posterior"'))
    export_dataset(cfg, tmp_path / "a.h5", progress=False)
    export_dataset(cfg, tmp_path / "b.h5", progress=False)
    a = arrays_of(tmp_path / "a.h5")
    assert_same_arrays(a, arrays_of(tmp_path / "b.h5"))
    fx = [json.loads(p)["system"]["camera"]["K"][0][0] for p in a["params"]]
    assert fx[0] != fx[1] and all(abs(f - d["camera"]["K"][0][0]) < 20 for f in fx)
