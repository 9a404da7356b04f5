"""The traditional decision's error model (unwrap.decision_error, issue 21): monotone where physics
says so, the noise model where no bias cue speaks, the fit recovers planted coefficients and
keeps its sign bounds, and the gate never changes an order the model is sure of."""
from __future__ import annotations

import math

import numpy as np
import pytest

from unwrap._xp import wrap
from unwrap.decision_error import (FEATURES, MAX_DISTANCE, MODEL, SIGNS, edge_distance, error_probability, features,
                                   fit, local_bias, probability_from_features)
from unwrap.errors import UnwrapError
from unwrap.spatial_orders import GATE, gate, graphcut_orders

TWO_PI = 2 * math.pi


def _plane(H=80, W=120, p_noise=1e-9, m=0.4):
    valid = np.ones((H, W), bool)
    prior = np.full((H, W), 5.0) + np.linspace(0, 3, W)[None, :].round()     # integers (orders 5..8)
    return (np.full((H, W), p_noise), prior, valid, np.full((H, W), m), np.full((H, W), m))


def test_the_shipped_coefficients_respect_the_sign_bounds():
    assert MODEL["version"] >= 1 and set(MODEL["coef"]) == set(FEATURES)
    for k, c in MODEL["coef"].items():
        assert SIGNS[k] * c >= 0, k
    assert "bench.decision_error_fit" in MODEL["fitted_on"]
    from unwrap.decision_error import GLOBAL_FEATURE, MODEL_GLOBAL
    assert set(MODEL_GLOBAL["coef"]) == set(FEATURES) | {GLOBAL_FEATURE}
    for k, c in MODEL_GLOBAL["coef"].items():
        assert SIGNS[k] * c >= 0, k


def test_more_distance_from_invalid_pixels_never_raises_the_error_probability():
    p_noise, prior, valid, m_lo, m_hi = _plane()
    valid[:, :2] = False                          # a shadow / background strip on the left
    p = error_probability(p_noise, prior, valid, m_lo, m_hi)
    row = p[40, 2:80]                             # distance 1 .. 78 px from the strip
    assert np.all(np.diff(row) <= 1e-15)
    if MODEL["coef"]["log_edge_distance"] < 0:
        assert row[0] > row[-1]
    assert np.all(p[~valid] == 0)


def test_more_modulation_never_raises_the_error_probability():
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(0, 0.1, 200), rng.uniform(-6, 0, 200), rng.uniform(-6, 0, 200),
                         rng.uniform(0, math.log1p(MAX_DISTANCE), 200), rng.uniform(0, 0.5, 200),
                         rng.uniform(0, 0.5, 200)])
    base = probability_from_features(X)
    for col, name in ((1, "log_mod_low"), (2, "log_mod_high"), (3, "log_edge_distance")):
        Y = X.copy()
        Y[:, col] += 0.5                          # more modulation / farther from an edge
        assert np.all(probability_from_features(Y) <= base + 1e-15), name
    for col in (4, 5):
        Y = X.copy()
        Y[:, col] = np.minimum(Y[:, col] + 0.1, 0.5)  # a larger coherent offset of the prior
        assert np.all(probability_from_features(Y) >= base - 1e-15)
    assert np.all(base >= X[:, 0] - 1e-15)        # never more sure than the noise model


def test_a_flat_lit_plane_far_from_edges_reproduces_the_noise_model():
    """No bias cue (no edge, the prior on integers, modulation 0.4): the noise model's probability
    plus a floor of at most 3e-3 (the fitted model's rate of errors the validation scenes show far
    from any cue: 1.5e-3), in the noise model's order."""
    last = None
    for pn in (1e-9, 1e-3, 0.02, 0.2, 0.6):
        p_noise, prior, valid, m_lo, m_hi = _plane(p_noise=pn)
        p = error_probability(p_noise, prior, valid, m_lo, m_hi)
        assert np.all(p >= pn - 1e-15)
        assert np.abs(p - pn).max() < 3e-3, pn
        assert last is None or p.min() > last
        last = p.max()


def test_local_bias_sees_a_coherent_offset_and_averages_noise_out():
    rng = np.random.default_rng(1)
    H, W = 60, 60
    valid = np.ones((H, W), bool)
    prior = 7 + rng.normal(0, 0.05, (H, W))
    prior[20:40, 20:40] += 0.45                   # a coherent offset of 0.45 fringe over a patch
    b = local_bias(prior, valid)
    assert np.median(b[25:35, 25:35]) == pytest.approx(0.45, abs=0.03)
    assert np.median(b[:10, :10]) < 0.03
    assert np.all(b[~valid] == 0)


def test_edge_distance_is_euclidean_and_capped():
    valid = np.ones((10, 200), bool)
    valid[:, 0] = False
    d = edge_distance(valid)
    assert d[5, 1] == 1 and d[5, 10] == 10 and d[5, 150] == MAX_DISTANCE and d[5, 0] == 0
    assert np.all(edge_distance(np.ones((5, 5), bool)) == MAX_DISTANCE)


def test_the_fit_recovers_planted_coefficients_and_keeps_its_signs():
    rng = np.random.default_rng(2)
    n = 200_000
    X = np.column_stack([rng.uniform(0, 0.05, n) * (rng.uniform(size=n) < 0.3), rng.uniform(-5, -0.5, n),
                         rng.uniform(-5, -0.5, n), rng.uniform(0, math.log1p(MAX_DISTANCE), n),
                         rng.uniform(0, 0.5, n), rng.uniform(0, 0.5, n)])
    true = {"version": 1, "intercept": -4.0,
            "coef": {"log_mod_low": -0.8, "log_mod_high": -0.3, "log_edge_distance": -1.2, "local_bias": 6.0,
                     "local_bias_wide": 2.0}}
    y = rng.uniform(size=n) < probability_from_features(X, true)
    m = fit(X, y, l2=0.0)
    for k, c in true["coef"].items():
        assert m["coef"][k] == pytest.approx(c, abs=0.25 * abs(c) + 0.1), k
    # data that says "more modulation, more errors": the bound keeps the coefficient at 0
    y2 = rng.uniform(size=n) < 1 / (1 + np.exp(-(-2.0 + 1.5 * (X[:, 1] + 3))))
    m2 = fit(X, y2)
    assert m2["coef"]["log_mod_low"] <= 0 and m2["coef"]["log_mod_low"] == pytest.approx(0, abs=1e-6)
    with pytest.raises(UnwrapError, match="needs at least 10"):
        fit(X[:100], np.zeros(100, bool))
    with pytest.raises(UnwrapError, match="expected X"):
        fit(X[:, :3], y)


def test_shapes_are_checked():
    with pytest.raises(UnwrapError, match="one \\(H, W\\) shape"):
        features(np.zeros((3, 4)), np.zeros((3, 4)), np.ones((3, 5), bool), np.zeros((3, 4)), np.zeros((3, 4)))


def _scene(bias_fringes, noise=0.004, seed=0):
    """MF (1, 16), 1024-px pattern, a wall (valid) with a shadow strip; the unit phase biased by
    ``bias_fringes`` in a band beside the strip (interreflection's signature)."""
    rng = np.random.default_rng(seed)
    H, W, f, width = 90, 200, 16, 1024
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    u = 120 + 3.5 * x + 0.4 * y
    Phi = lambda f: TWO_PI * f * u / width       # noqa: E731
    valid = np.ones((H, W), bool)
    valid[:, 60:66] = False                        # the cast shadow
    band = (x >= 66) & (x < 76)
    lo = wrap(Phi(1) + np.where(band, bias_fringes * TWO_PI / f, 0.0) + rng.normal(0, noise, (H, W)))
    hi = wrap(Phi(f) + rng.normal(0, noise, (H, W)))
    k_true = np.rint((Phi(f) - hi) / TWO_PI).astype(np.int64)
    return lo, hi, k_true, valid, band, (1, f), width


@pytest.mark.parametrize("row", list(GATE))
def test_the_gate_never_changes_an_order_the_model_is_sure_of(row):
    """A clean, unbiased scene the traditional decode gets right and a sure but wrong proposal
    everywhere: the gate (the shipped thresholds on the decision error model) keeps every order
    whose error probability is below its threshold, and those are most of the pixels."""
    lo, hi, k_true, valid, band, freqs, width = _scene(0.0)
    m = np.full(lo.shape, 0.4)
    r = graphcut_orders("mf", lo, hi, freqs, valid, 0.004 * 1.0, 0.004, width=width)
    assert np.all(r.order_traditional[r.valid] == k_true[r.valid])
    p = error_probability(r.p_wrong_traditional, r.prior, r.valid, m, m)
    g = GATE[row]
    assert g["min_p_wrong"] > 0
    wrong = np.where(r.valid, r.order_traditional + 1, -1)
    out = gate(wrong, r.order_traditional, r.valid, p, confidence=np.ones(lo.shape),
               min_confidence=g["min_confidence"], min_p_wrong=g["min_p_wrong"])
    sure = r.valid & (p < g["min_p_wrong"])
    assert sure.sum() > 0.5 * r.valid.sum()        # the threshold lies above the model's no-cue floor
    assert np.array_equal(out[sure], k_true[sure])
    assert np.array_equal(out[r.valid & ~sure], wrong[r.valid & ~sure])


def test_the_shipped_gate_lies_on_the_calibration_grid_above_the_models_no_cue_floor():
    """GATE holds a point of bench.spatial_unwrap's grid (what --calibrate-gate can return), and the
    grid's first error-probability threshold is still twice MODEL's probability where no bias cue
    speaks (a refit that moves that floor must move the grid too, or the gate's "sure" set changes)."""
    from bench.spatial_unwrap import CONF_GRID, P_WRONG_GRID

    for grid in (P_WRONG_GRID, CONF_GRID):
        assert all(a < b for a, b in zip(grid, grid[1:])), grid      # a grid, each point once
    assert 0.0 <= CONF_GRID[0] and CONF_GRID[-1] < 1.0                # probabilities of the new label
    for row, g in GATE.items():
        assert g["min_p_wrong"] in P_WRONG_GRID, row
        assert g["min_confidence"] in CONF_GRID, row
    floor = error_probability(*_plane(p_noise=0.0))[40, 60]
    assert 0.0 < floor and abs(2 * floor / P_WRONG_GRID[0] - 1) < 0.1
    assert min(g["min_p_wrong"] for g in GATE.values()) >= P_WRONG_GRID[0]


def test_a_biased_band_beside_a_shadow_is_less_sure_than_the_noise_model_says():
    """0.45 fringe of coherent bias beside the shadow: the noise model still calls most of the
    band's (right and wrong) decisions sure; the decision error model raises them above its
    value far from the edge."""
    lo, hi, k_true, valid, band, freqs, width = _scene(0.45)
    m = np.full(lo.shape, 0.4)
    r = graphcut_orders("mf", lo, hi, freqs, valid, 0.004, 0.004, width=width)
    p = error_probability(r.p_wrong_traditional, r.prior, r.valid, m, m)
    far = r.valid & ~band & (np.arange(lo.shape[1])[None, :] > 120)
    assert np.median(p[band & r.valid]) > 10 * np.median(p[far])
    assert np.median(p[band & r.valid]) > np.median(r.p_wrong_traditional[band & r.valid])
