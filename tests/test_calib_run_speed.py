"""`calib run` made fast (issue 22) without moving the result: on the paper's 9 real views every
calibration parameter stays within 1e-9 (relative) of what main's code computed before the speed
work (tests/data/dp_tpu_calib_run_reference.json, recorded at 920e6f4), and the reported
uncertainties within 1e-6; the run reports its peak memory; many views draw one summary figure."""
import json
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import shared_data

REF = Path(__file__).resolve().parent / "data" / "dp_tpu_calib_run_reference.json"


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
            for a, b in zip(np.ravel(got[dev][key]), np.ravel(ref[dev][key])):   # each entry relative
                assert abs(a - b) <= 1e-9 * max(abs(b), 1e-9 * np.abs(ref[dev][key]).max()), (dev, key, a, b)
    _close(got["board_warp_mm"], ref["board_warp_mm"], 1e-9, "board warp")
    for g, w in zip(got["board_poses"], ref["board_poses"]):
        for frame in ("cam_board",):
            _close(g[frame]["R"], w[frame]["R"], 1e-9, f"pose {g['view']} R")
            _close(g[frame]["t"], w[frame]["t"], 1e-9, f"pose {g['view']} t")
    assert got["solver"]["iterations"] == ref["solver"]["iterations"]
    for dev, block in ref["uncertainties_1sigma"].items():
        for name, value in block.items():
            _close(got["uncertainties_1sigma"][dev][name], value, 1e-6, f"sigma {dev}.{name}")
    for key in ("skew_px", "sigma_px"):
        for dev, value in ref["skew_check"][key].items():
            _close(got["skew_check"][key][dev], value, 1e-6, f"skew check {key} {dev}")


def test_the_run_reports_its_peak_memory(paper_run):
    got, _ = paper_run
    assert 20 < got["run"]["peak_memory_mb"] < 100000
