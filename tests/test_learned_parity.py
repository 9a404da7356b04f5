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

    model = constant_model(tmp_path / "zero.pt", 0)
    model_meta_ratio_ok = (8.0 / 48.0) >= 1 / 8                 # the tiny files hold MF (1, 8)
    assert model_meta_ratio_ok
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
