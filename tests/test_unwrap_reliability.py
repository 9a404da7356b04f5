"""Reliability theory vs Monte Carlo of real noisy N-step stacks, and the fringe planner."""
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from unwrap import UnwrapError, error_rate, monte_carlo_error_rate, phase_error_pdf, phase_sigma
from unwrap.plan import format_table, plan_fringes

STEPS = 3


def _sigma_phi_for(method, freqs, target):
    g = lambda ls: math.log(max(error_rate(method, freqs, math.exp(ls)), 1e-300)) - math.log(target)  # noqa: E731
    return math.exp(brentq(g, math.log(2e-3), math.log(1.0), xtol=1e-6))


CASES = [("mf", (1, 8, 48), (1e-4, 1e-2, 0.5)),
         ("mf", (1, 4, 16, 64), (1e-4, 0.1)),
         ("mw", (70, 64, 59), (1e-4, 1e-2, 0.5)),
         ("mw", (48, 47), (1e-3, 0.5)),
         ("nt", (47, 48), (1e-4, 1e-2, 0.5)),
         ("cgray", (32,), (1e-4, 1e-2))]


@pytest.mark.slow
@pytest.mark.parametrize("method, freqs, targets", CASES)
def test_predicted_error_rate_matches_monte_carlo_within_10_percent(method, freqs, targets):
    for target in targets:
        s_phi = _sigma_phi_for(method, freqs, target)
        predicted = error_rate(method, freqs, s_phi)
        n = int(min(8e6, max(2e5, 1000 / predicted)))
        sigma = s_phi * math.sqrt(STEPS / 2)  # intensity noise for B = 1, N = 3
        measured, n_err = monte_carlo_error_rate(method, freqs, steps=STEPS, sigma=sigma,
                                                 n_pixels=n, seed=7)
        assert abs(measured / predicted - 1) < 0.10, (method, freqs, target, measured, predicted, n_err)


def test_phase_error_density_is_normalised_and_gaussian_at_high_snr():
    e = np.linspace(-np.pi, np.pi, 200001)
    for s in (0.01, 0.3, 3.0):
        assert np.trapz(phase_error_pdf(e, s), e) == pytest.approx(1.0, abs=1e-6)
    s = 0.01
    gauss = np.exp(-0.5 * (e / s) ** 2) / (s * math.sqrt(2 * math.pi))
    core = np.abs(e) < 3 * s
    assert np.allclose(phase_error_pdf(e[core], s), gauss[core], rtol=2e-3)
    assert phase_sigma(2.0, 12, 60.0) == pytest.approx(math.sqrt(2 * 4 / (12 * 3600)))


def test_error_rate_grows_with_noise_and_with_the_ladder_ratio():
    rates = [error_rate("mf", (1, 8, 48), s) for s in (0.05, 0.1, 0.2)]
    assert rates[0] < rates[1] < rates[2]
    assert error_rate("mf", (1, 96), 0.05) > 100 * error_rate("mf", (1, 8, 96), 0.05)
    with pytest.raises(UnwrapError):
        error_rate("xx", (1, 8), 0.1)


def test_plan_fringes_table_lists_images_and_error_rates():
    rows = plan_fringes(["mf:1,8,48", "nt:47,48", "cgray:32"], (3, 12), sigma=3.0, modulation=50.0)
    assert [r["images"] for r in rows] == [9, 36, 6, 24, 9, 18]
    nt = [r["error_rate"] for r in rows if r["method"] == "nt"]
    assert nt[1] < nt[0]
    text = format_table(rows, max_error_rate=1e-3)
    assert "| mf:1,8,48 | 12 | 36 |" in text and "over limit" in text
