"""The report's twin-vs-real section of the learned unwrapping: the noise estimator follows the
sensor's full well, and the section's table and verdict come from the scored files."""
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from dataset_helpers import tiny_config  # noqa: E402
from test_learned_use import constant_model  # noqa: E402


@pytest.fixture(scope="module")
def two_noise_levels(tmp_path_factory):
    from synth.export.dataset import export_dataset

    out = {}
    for fw in (1500, 6000):
        d = tmp_path_factory.mktemp(f"fw{fw}")
        cfg = tiny_config(d, samples=2, frequencies="[1, 8]", steps=4,
                          effects=f"noise = {{full_well_e = {fw}, read_noise_e = 1}}\nexposure = 0.8")
        export_dataset(cfg, d / "set.h5", progress=False)
        out[fw] = d / "set.h5"
    return out


@pytest.mark.slow
def test_capture_noise_follows_the_sensor_full_well(two_noise_levels):
    """Shot noise: sigma_I ~ 1/sqrt(full well), so 4x the full well halves the measured noise."""
    from experiments.learned_parity import capture_noise
    from synth.effects.sensor import shot_noise_full_well

    lo, hi = capture_noise(two_noise_levels[1500]), capture_noise(two_noise_levels[6000])
    assert lo["steps"] == 4 and lo["pixels"] > 1000
    assert 1.6 < lo["sigma_I"] / hi["sigma_I"] < 2.5
    assert 1.6 < lo["sigma_phase_rad"] / hi["sigma_phase_rad"] < 2.5
    full_well = {k: shot_noise_full_well(n["modulation"], n["sigma_I"]) for k, n in (("lo", lo), ("hi", hi))}
    assert 2.5 < full_well["hi"] / full_well["lo"] < 6.0


@pytest.mark.slow
def test_parity_section_scores_both_sides_and_states_a_verdict(two_noise_levels, tmp_path):
    from reports.html import to_markdown
    from experiments.learned_parity import parity
    from reports.learned_parity import section

    import h5py

    model = constant_model(tmp_path / "zero.pt", 0)
    for path in two_noise_levels.values():                      # the tiny files hold MF (1, 8), 4 steps
        with h5py.File(path, "r") as h5:
            assert [float(f) for f in h5.attrs["frequencies"]] == [1.0, 8.0]
    (title, blocks), summary = section(parity([two_noise_levels[1500]], [two_noise_levels[6000]], model,
                                              frequencies=(8,)))
    rows = summary["rows"]
    assert [r["data"] for r in rows] == ["real", "twin"] and all(r["f"] == 8 for r in rows)
    for r in rows:                                              # a zero-correction model is the traditional order
        assert r["learned"] == r["traditional"] and r["pixels"] > 1000
    assert "behaves on the real capture as on its twin" in summary["verdict"]
    md = to_markdown("t", [(title, blocks)])
    assert "| real | 8 |" in md and "Verdict" in md and "Figure: wrong fringe orders" in md


def test_traditional_gap_says_whether_the_matched_noise_explains_the_real_errors():
    from reports.learned_parity import traditional_gap
    from unwrap.learned.metrics import ErrorCount

    def row(data, f, wrong, counted=10_000):
        return {"data": data, "f": f, "traditional": ErrorCount(wrong, counted)}

    explained = traditional_gap([row("real", 16.0, 12), row("twin", 16.0, 10), row("twin", 48.0, 300)])
    assert "real 0.120 %" in explained and "accounts for the real errors" in explained
    unexplained = traditional_gap([row("real", 16.0, 45), row("twin", 16.0, 10)])
    assert "ratio 4.5" in unexplained and "noise alone does not account" in unexplained
    assert traditional_gap([row("twin", 16.0, 10)]) == ""
    assert traditional_gap([row("real", 16.0, 10), row("twin", 48.0, 10)]) == ""


def test_verdict_names_a_twin_that_under_predicts_the_real_errors():
    """Issue 21: the skull's real traditional error is 1.8x its twin's (4.4x against the reference
    before its stored-phase fix); the verdict must say so."""
    from reports.learned_parity import verdict
    from unwrap.learned.metrics import ErrorCount

    def row(data, trad, learned, counted=100_000):
        return {"data": data, "f": 16.0, "traditional": ErrorCount(trad, counted), "learned": ErrorCount(learned, counted)}

    v = verdict([row("real", 450, 370), row("twin", 102, 112)])
    assert "the twin under-predicts real errors 4.4x" in v and "behaves on the real capture" not in v
    v = verdict([row("real", 181, 109), row("twin", 101, 111)])    # the skull today (calib demo)
    assert "the twin under-predicts real errors 1.8x" in v and "behaves on the real capture" not in v
    v = verdict([row("real", 181, 109), row("twin", 5338, 5000)])   # a twin 30x too noisy vouches for nothing
    assert "the twin over-predicts real errors 29.5x" in v and "behaves on the real capture" not in v
    assert "behaves on the real capture as on its twin" in verdict([row("real", 120, 110), row("twin", 100, 95)])


@pytest.mark.slow
def test_calib_report_with_learned_files_adds_the_parity_section(tmp_path, capsys):
    """The passing case of `calib report --learned-real/--learned-twin/--learned-model`: the report
    carries the learned parity section at the frequency the files hold (16, one of the section's),
    and a zero-correction model scores as the traditional order on both."""
    from calib import default_system
    from calib.io.calibration_json import write_calibration_json
    from sltwin.cli import main
    from synth.export.dataset import export_dataset

    files = {}
    for fw in (1500, 6000):
        d = tmp_path / f"fw{fw}"
        d.mkdir()
        cfg = tiny_config(d, samples=2, frequencies="[1, 16]", steps=4,
                          effects=f"noise = {{full_well_e = {fw}, read_noise_e = 1}}\nexposure = 0.8")
        export_dataset(cfg, d / "set.h5", progress=False)
        files[fw] = d / "set.h5"
    cal = write_calibration_json(default_system(), tmp_path / "calibration.json")
    model = constant_model(tmp_path / "zero.pt", 0)
    out = tmp_path / "rep"
    assert main(["report", "--real", str(cal), "--twin", str(cal), "--learned-real", str(files[1500]),
                 "--learned-twin", str(files[6000]), "--learned-model", str(model), "-o", str(out)]) == 0
    assert "behaves on the real capture as on its twin" in capsys.readouterr().out
    md = (out / "report.md").read_text()
    assert "Verdict" in md
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[1:-1]] for line in md.splitlines()
            if line.startswith(("| real | 16 |", "| twin | 16 |"))}
    assert sorted(rows) == ["real", "twin"]
    for data, (_, f, samples, pixels, trad, filtered, learned, check) in rows.items():
        assert samples == "2" and int(pixels) > 30_000 and check.endswith("ok")
        assert learned == trad                                  # zero correction = the traditional order


def test_noise_curve_recovers_the_sensor_of_synthetic_residuals():
    """noise_curve inverts the plane-residual noise per modulation decile: residuals drawn from a
    sensor of 10,000 e- full well and 30 e- read noise (8-bit quantisation on top) give it back."""
    import math

    import numpy as np

    from experiments.learned_parity import noise_curve

    rng = np.random.default_rng(3)
    N, fw, read = 3, 10_000.0, 30.0
    q2 = 1.0 / (12.0 * 255.0 ** 2)
    B = rng.uniform(0.03, 0.3, 400_000)
    sigma_I = np.sqrt((read / fw) ** 2 + q2 + B / fw)
    sigma_phase = sigma_I / (B * math.sqrt(N / 2.0)) / math.sqrt(25.0 / 24.0)   # the centre residual's dof factor
    c = noise_curve(rng.normal(0.0, sigma_phase), B, N)
    assert len(c["modulation"]) == 10 and np.all(np.diff(c["sigma_I"]) > 0)
    assert c["full_well_e"] == pytest.approx(fw, rel=0.1)
    assert c["read_noise_e"] == pytest.approx(read, rel=0.15)
    flat = noise_curve(rng.normal(0.0, 0.01 / B), B, N)      # phase noise ~ 1/B: constant sigma_I, no shot noise
    assert flat["full_well_e"] is None or flat["full_well_e"] > 1e5   # 10x the sensor above: no shot noise


def test_parity_section_shows_the_noise_against_modulation_when_measured():
    """The noise paragraph gains the capture's noise curve (noise_curve's ends) when the twin info holds it."""
    from reports.learned_parity import section

    curve = {"modulation": [0.04, 0.2], "sigma_I": [0.0035, 0.0056], "full_well_e": 1e4, "read_noise_e": 30.0}
    info = {"noise_real": {"sigma_I": 0.0047, "sigma_phase_rad": 0.03, "modulation": 0.13, "steps": 3, "curve": curve},
            "noise_twin": {"sigma_I": 0.0016, "sigma_phase_rad": 0.027, "modulation": 0.047, "steps": 3},
            "full_well": 1e5}
    (_, blocks), _ = section({"rows": [], "model_meta": {}}, twin_info=info)
    text = " ".join(str(b[1]) for b in blocks)
    assert "capture sigma_I 0.0035 at B 0.040 -> 0.0056 at B 0.200" in text and "twin sigma_I" not in text
    (_, blocks), _ = section({"rows": [], "model_meta": {}}, twin_info={**info, "noise_real": {"sigma_I": 0.0047}})
    assert "Noise against modulation" not in " ".join(str(b[1]) for b in blocks)
