"""The graph cut's depth-edge weight (unwrap.spatial_edges, issue 21 item 4): a small surface one
fringe in front of its surroundings, whose high phase is continuous with them, keeps its own orders;
noise and bias bands do not weaken the smoothness."""
from __future__ import annotations

import math

import numpy as np
import pytest

from unwrap._xp import wrap
from unwrap.errors import UnwrapError
from unwrap.spatial_edges import same_surface_probability, scale_grid_weights, scale_pair_weights
from unwrap.spatial_orders import DEFAULTS, edge_weights, graphcut_orders

TWO_PI = 2 * math.pi


def _one_fringe_step(noise: float, seed: int = 0):
    """MF (1, 16) over a 1024-px pattern, 60 x 80 px: a smooth surface, and a 5 x 5 px patch (a small
    object in front of it) displaced by exactly one period of the high frequency (64 projector px):
    its high phase is continuous with the surroundings, its unit phase steps by 1/16 of a period,
    so the prior steps by one fringe (< 1.5: no hard cut). Phase noise ``noise`` rad in both."""
    rng = np.random.default_rng(seed)
    H, W, f, width = 60, 80, 16, 1024
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    u = 200 + 2.5 * x + 0.7 * y
    patch = (np.abs(x - 40) <= 2) & (np.abs(y - 30) <= 2)
    u = u + np.where(patch, width / f, 0.0)
    lo = wrap(TWO_PI * u / width + rng.normal(0, noise, (H, W)))
    hi = wrap(TWO_PI * f * u / width + rng.normal(0, noise, (H, W)))
    k_true = np.rint((TWO_PI * f * u / width - hi) / TWO_PI).astype(np.int64)
    return lo, hi, k_true, patch, (1, f), width


def test_a_one_fringe_depth_step_with_a_continuous_high_phase_keeps_its_orders():
    """The traditional decode is right everywhere; without the depth-edge weight the smoothness
    (20 edges x 8 nats) outweighs the patch's 25 sure pixels (~6 nats each, capped by the
    likelihood's outlier part) and pulls the patch one fringe back, to its surroundings' orders;
    with the shipped weight (the prior's one-fringe step is e^100 more likely a step than noise)
    the patch keeps them."""
    lo, hi, k_true, patch, freqs, width = _one_fringe_step(0.005)
    valid = np.ones(lo.shape, bool)
    off = graphcut_orders("mf", lo, hi, freqs, valid, 0.005, 0.005, width=width, step_odds=0.0)
    assert np.all(off.order_traditional == k_true)
    assert np.all(off.order[patch] == k_true[patch] - 1)          # the failure: right orders broken
    assert DEFAULTS["step_odds"] > 0
    on = graphcut_orders("mf", lo, hi, freqs, valid, 0.005, 0.005, width=width)
    assert np.all(on.order == k_true)


def test_the_weight_keeps_the_smoothness_where_the_step_is_noise_or_bias():
    odds, o = DEFAULTS["step_odds"], DEFAULTS["outlier"]
    # a smooth surface crossing a fringe wrap: the raw prior steps by -1, the wrapped phase by +2 pi - 0.2
    assert same_surface_probability(-1.0, TWO_PI - 0.2, 0.02, 0.02, odds=odds, outlier=o) > 0.99
    # a one-fringe step of a sure prior is cut to ~1/9 of the weight, of a noisy one (0.3 fringes) mostly kept
    sure = same_surface_probability(1.0, 0.1, 0.02, 0.02, odds=odds, outlier=o)
    noisy = same_surface_probability(1.0, 0.1, 0.3, 0.3, odds=odds, outlier=o)
    assert sure < 0.15 < 0.5 < noisy
    # a step that fits neither (0.75 fringe with a sure prior: a bias band's boundary) is not a depth edge
    assert same_surface_probability(0.75, 0.0, 0.02, 0.02, odds=odds, outlier=o) == pytest.approx(1 / (1 + odds))
    # odds 0 leaves every weight as it was
    assert np.all(same_surface_probability(np.linspace(-3, 3, 13), 0.0, 0.01, 0.01, odds=0.0, outlier=o) == 1)
    with pytest.raises(UnwrapError, match="step_odds"):
        same_surface_probability(1.0, 0.0, 0.1, 0.1, odds=-1.0, outlier=o)
    with pytest.raises(UnwrapError, match="outlier"):
        same_surface_probability(1.0, 0.0, 0.1, 0.1, odds=1.0, outlier=1.0)


def test_grid_and_pair_weights_agree_and_keep_cut_edges_cut():
    lo, hi, k_true, patch, freqs, width = _one_fringe_step(0.0)
    prior = (16 * np.mod(lo, TWO_PI) - np.mod(hi, TWO_PI)) / TWO_PI      # any real-valued prior map
    valid = np.ones(lo.shape, bool)
    valid[10, 10] = False
    wx, wy = edge_weights(hi, valid, weight=8.0)
    sx, sy = scale_grid_weights(wx, wy, prior, hi, 0.02, odds=0.1, outlier=0.05)
    assert np.all(sx[wx == 0] == 0) and np.all(sy[wy == 0] == 0) and np.all(sx <= wx) and np.all(sy <= wy)
    H, W = lo.shape
    p = np.array([5 * W + 7, 30 * W + 37])                 # a horizontal pair of each kind: far from / at the patch
    _, _, w = scale_pair_weights(p, p + 1, np.full(2, 8.0), prior, hi, 0.02, odds=0.1, outlier=0.05)
    assert w == pytest.approx([sx[5, 7], sx[30, 37]])
    assert sx[30, 37] < 1.0 < 7.0 < sx[5, 7]


@pytest.mark.parametrize("seed", [0, 1])
def test_a_noisy_one_fringe_step_is_not_worse_than_traditional(seed):
    """Noisier phases (0.03 rad: the prior's noise is ~0.08 fringe, its step's 0.11): the step is
    still ~9 of its sigmas from no step, so the edge is weakened and the patch keeps its orders
    (without the weight it is pulled back, as in the noise-free case). With a prior a few times
    noisier the step is no longer significant and the smoothness decides again (module docstring)."""
    lo, hi, k_true, patch, freqs, width = _one_fringe_step(0.03, seed)
    valid = np.ones(lo.shape, bool)
    off = graphcut_orders("mf", lo, hi, freqs, valid, 0.03, 0.03, width=width, step_odds=0.0)
    assert np.all(off.order[patch] != k_true[patch])
    r = graphcut_orders("mf", lo, hi, freqs, valid, 0.03, 0.03, width=width)
    right_t = r.order_traditional == k_true
    assert np.all(r.order[patch & right_t] == k_true[patch & right_t])
    assert (r.order != k_true).sum() <= (~right_t).sum()
