"""`calib run` made fast (issue 22) without moving the result: on the paper's 9 real views every
calibration parameter stays within 1e-9 (relative; RTOL below for other CPUs) of what main's code computed before the speed
work (tests/data/dp_tpu_calib_run_reference.json, recorded at 920e6f4), and the reported
uncertainties within 1e-6 (SIGMA_RTOL for other CPUs); the run reports its peak memory; many views draw one summary figure."""
import json
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import shared_data

REF = Path(__file__).resolve().parent / "data" / "dp_tpu_calib_run_reference.json"
#: On the machine that recorded REF every parameter agrees within 1e-9 relative (issue 22's goal).
#: Another BLAS kernel rounds the solve differently and moves the poorly determined directions by
#: up to 7e-9 relative (camera t under OPENBLAS_CORETYPE=SkylakeX), so the test holds 1e-7: far
#: below what any change to the adjustment itself moves.
RTOL = 1e-7
#: The reported sigmas agree within 1e-6 on the recording machine and move by up to 1.1e-6 under
#: other kernels (camera k3, SkylakeX). REF's were computed with a Jacobian by central differences;
#: the adjustment's analytic one gives sigmas 5.1e-7 (camera k3) from them: the differences'
#: rounding error (tests/test_calib_run_lean.py).
SIGMA_RTOL = 1e-5


def _close(got, want, rtol, what):
    got, want = np.asarray(got, float), np.asarray(want, float)
    scale = max(np.abs(want).max(), 1e-300)
    assert np.abs(got - want).max() <= rtol * scale, (what, got, want)


@pytest.fixture(scope="module")
def paper_run(tmp_path_factory):
    from sltwin.cli import main

    cam = shared_data("dp-tpu", "CamCalibResult_real.mat")
    prj = shared_data("dp-tpu", "PrjCalibResult_real.mat")
    out = tmp_path_factory.mktemp("run")
    assert main(["run", "--observations", str(cam), str(prj), "-o", str(out), "-q"]) == 0
    return json.loads((out / "calibration.json").read_text()), out


def test_every_parameter_within_1e9_of_mains_result_on_the_paper_views(paper_run):
    got, _ = paper_run
    ref = json.loads(REF.read_text())
    for dev in ("camera", "projector"):
        for key in ("K", "distortion", "R", "t"):
            floor = np.zeros(np.size(ref[dev][key]))
            if key == "distortion":
                # the distortion terms are poorly determined on 9 views (3 sigma > |value|, correlations
                # -0.99): another BLAS kernel moves them by ~2e-9 relative (OPENBLAS_CORETYPE=SkylakeX,
                # k1), so each may also differ by 1e-8 of its own 1-sigma uncertainty
                names = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")[:len(floor)]
                floor = 1e-8 * np.array([ref["uncertainties_1sigma"][dev].get(n, 0.0) for n in names])
            for a, b, f in zip(np.ravel(got[dev][key]), np.ravel(ref[dev][key]), floor):   # each entry relative
                assert abs(a - b) <= max(RTOL * max(abs(b), 1e-9 * np.abs(ref[dev][key]).max()), f), (dev, key, a, b)
    _close(got["board_warp_mm"], ref["board_warp_mm"], RTOL, "board warp")
    for g, w in zip(got["board_poses"], ref["board_poses"]):
        for frame in ("cam_board",):
            _close(g[frame]["R"], w[frame]["R"], RTOL, f"pose {g['view']} R")
            _close(g[frame]["t"], w[frame]["t"], RTOL, f"pose {g['view']} t")
    assert got["solver"]["iterations"] == ref["solver"]["iterations"]
    for dev, block in ref["uncertainties_1sigma"].items():
        for name, value in block.items():
            _close(got["uncertainties_1sigma"][dev][name], value, SIGMA_RTOL, f"sigma {dev}.{name}")
    for key in ("skew_px", "sigma_px"):
        for dev, value in ref["skew_check"][key].items():
            _close(got["skew_check"][key][dev], value, SIGMA_RTOL, f"skew check {key} {dev}")


def test_the_run_reports_its_peak_memory(paper_run):
    got, _ = paper_run
    assert 20 < got["run"]["peak_memory_mb"] < 100000
