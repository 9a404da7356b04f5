"""The twin-equivalence report: content, refusals, and a real headless browser."""
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from calib import default_system
from calib.io.calibration_json import system_to_dict
from reports.errors import ReportError
from reports.twin_report import write_twin_report
from tests.conftest import REPO, shared_data

ARTIFACTS = REPO / "out" / "test-artifacts"


def _write_json(path, system, **extra):
    path.write_text(json.dumps(system_to_dict(system, **extra)))
    return path


def _perturbed(system, dfx=3.0):
    cam = system.camera
    K = np.array(cam.K)
    K[0, 0] += dfx
    return type(system)(cam.with_(K=K), system.projector, {})


def test_report_puts_differences_in_units_of_sigma_and_flags_beyond_3_sigma(tmp_path):
    s = default_system()
    std = {"camera": {"fx": 0.5, "fy": 0.5}, "projector": {"fx": 1.0}}
    real = _write_json(tmp_path / "real.json", s, uncertainties_1sigma=std)
    twin = _write_json(tmp_path / "twin.json", _perturbed(s, dfx=3.0), uncertainties_1sigma=std)
    summary = write_twin_report([real], [twin], tmp_path / "rep")
    fx = next(p for p in summary["parameters"] if p["device"] == "camera" and p["parameter"] == "fx")
    assert fx["difference"] == pytest.approx(3.0) and fx["z"] == pytest.approx(3.0 / np.sqrt(0.5))
    assert summary["beyond_3_sigma"] == ["camera.fx"]
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "beyond 3 sigma" in md and "Table S4" in md and "INCONSISTENT" in md


def test_report_refuses_mismatched_image_sizes(tmp_path):
    s = default_system()
    real = _write_json(tmp_path / "real.json", s)
    other = type(s)(s.camera.with_(size=(1280, 960)), s.projector, {})
    twin = _write_json(tmp_path / "twin.json", other)
    with pytest.raises(ReportError, match=r"camera image sizes differ.*\(640, 480\) vs .*\(1280, 960\)"):
        write_twin_report([real], [twin], tmp_path / "rep")


def test_report_refuses_other_units_and_missing_keys(tmp_path, capsys):
    from sltwin.cli import main

    s = default_system()
    real = _write_json(tmp_path / "real.json", s)
    d = system_to_dict(s)
    d["units"] = "m"
    (tmp_path / "m.json").write_text(json.dumps(d))
    assert main(["report", "--real", str(real), "--twin", str(tmp_path / "m.json"), "-o", str(tmp_path / "r")]) == 2
    assert "units = 'm'" in capsys.readouterr().err
    del d["projector"]
    d["units"] = "mm"
    (tmp_path / "p.json").write_text(json.dumps(d))
    assert main(["report", "--real", str(real), "--twin", str(tmp_path / "p.json"), "-o", str(tmp_path / "r")]) == 2
    assert "missing key(s) ['projector']" in capsys.readouterr().err


@pytest.fixture(scope="module")
def dp_tpu_report(tmp_path_factory):
    d = shared_data("dp-tpu")
    out = tmp_path_factory.mktemp("report")
    summary = write_twin_report([d / "CamCalibResult_real.mat", d / "PrjCalibResult_real.mat"],
                                [d / "CamCalibResult_sim.mat", d / "PrjCalibResult_sim.mat"], out)
    return out, summary


@pytest.mark.realdata
def test_dp_tpu_real_vs_twin_calibrations_agree_within_3_sigma(dp_tpu_report):
    _, summary = dp_tpu_report
    assert summary["beyond_3_sigma"] == []
    cy = next(p for p in summary["parameters"] if p["device"] == "projector" and p["parameter"] == "cy")
    assert cy["difference"] == pytest.approx(-39.207, abs=1e-3)  # the largest, -2.4 sigma


def _chromium():
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("chromium is not installed; `make test` installs it")
    return exe


def _browse(html_path: Path, screenshot: Path | None = None):
    exe = _chromium()
    common = [exe, "--headless=new", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
              "--enable-logging=stderr", "--v=0", "--virtual-time-budget=5000"]
    dom = subprocess.run(common + ["--dump-dom", html_path.as_uri()], capture_output=True, text=True, timeout=120)
    body = re.search(r"<body[^>]*>", dom.stdout)
    attrs = dict(re.findall(r'data-images-(ok|total)="(\d+)"', body.group(0) if body else ""))
    console_errors = [line for line in dom.stderr.splitlines() if "CONSOLE" in line]
    if screenshot is not None:
        screenshot.parent.mkdir(parents=True, exist_ok=True)
        subprocess.run(common + ["--window-size=1200,3000", f"--screenshot={screenshot}", html_path.as_uri()],
                       capture_output=True, text=True, timeout=120)
    return attrs, console_errors


@pytest.mark.realdata
def test_report_loads_in_a_real_browser_with_no_broken_image_and_no_console_error(dp_tpu_report):
    out, _ = dp_tpu_report
    shot = ARTIFACTS / "report_dp_tpu.png"
    attrs, console_errors = _browse(out / "report.html", shot)
    assert int(attrs["total"]) >= 4 and attrs["ok"] == attrs["total"]
    assert console_errors == []
    assert shot.exists() and shot.stat().st_size > 10_000


def test_the_browser_check_sees_a_broken_image(tmp_path):
    """Negative control: the same check on a page with a broken image fails."""
    page = tmp_path / "broken.html"
    from reports.html import SCRIPT
    page.write_text(f"<html><head><script>{SCRIPT}</script></head><body>"
                    "<img alt='ok' src='data:image/png;base64,iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mNk"
                    "YPhfDwAChwGA60e6kgAAAABJRU5ErkJggg=='><img alt='missing' src='nope.png'></body></html>")
    attrs, console_errors = _browse(page)
    assert attrs == {"ok": "1", "total": "2"}
    assert any("broken images: missing" in line for line in console_errors)


@pytest.mark.realdata
def test_fig3_real_phase_with_real_calibration_reproduces_with_the_papers_linear_method(tmp_path):
    d = shared_data("dp-tpu")
    summary = write_twin_report([d / "CamCalibResult_real.mat", d / "PrjCalibResult_real.mat"],
                                [d / "CamCalibResult_sim.mat", d / "PrjCalibResult_sim.mat"], tmp_path,
                                phases={"real": d / "standardball_phase_real.mat", "twin": d / "standardball_phase_sim.mat"})
    cells = {(r["phase"], r["calibration"], r["method"]): r for r in summary["sphere_matrix"]}
    assert len(cells) == 8
    rr = cells[("real", "real", "linear")]
    assert rr["rms_um"] == pytest.approx(58.541, rel=0.01) and rr["radius_mm"] == pytest.approx(25.2, abs=0.1)
    # every linear cell within 20 % of the paper's Fig. 3
    for (phase, cal, method), r in cells.items():
        if method == "linear":
            assert abs(r["rms_um"] / r["paper_um"] - 1) < 0.2, (phase, cal, r["rms_um"], r["paper_um"])
    assert "Fig. 3" in (tmp_path / "report.md").read_text()


def test_phase_map_of_the_wrong_size_is_refused(tmp_path):
    from calib.errors import TriangulationError
    from calib.triangulate import sphere_from_phase
    with pytest.raises(TriangulationError, match="does not match the camera image"):
        sphere_from_phase(default_system(), np.ones((100, 100)), 96.0)


def test_skew_and_distortion_the_twin_cannot_have_are_expected_differences_not_flags(tmp_path):
    s = default_system()
    std = {d: {p: 0.01 for p in ("skew", "k1", "k2", "p1", "p2", "k3")} for d in ("camera", "projector")}
    real = _write_json(tmp_path / "real.json", s, uncertainties_1sigma=std)
    twin = _write_json(tmp_path / "twin.json", s.ideal(), uncertainties_1sigma=std)   # Blender: ideal pinholes
    summary = write_twin_report([real], [twin], tmp_path / "rep")
    assert summary["beyond_3_sigma"] == []
    assert "camera.k1" in summary["expected_differences"] and "projector.skew" in summary["expected_differences"]
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "expected: the twin has none" in md and "ideal pinholes" in md
