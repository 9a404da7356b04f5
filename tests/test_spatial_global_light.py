"""The direct / global separation and the bias bound of the coarse phase (unwrap.global_light,
issue 21), and the bound in the graph cut's data term (unwrap.spatial_orders)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from unwrap._xp import wrap
from unwrap.global_light import GlobalLightError, bias_bound, pattern_offset_ratio
from unwrap.phase_shift import wrapped_phase
from unwrap.spatial_orders import graphcut_orders, prior_data_cost

TWO_PI = 2 * math.pi


def _capture(rng, n_px, *, a=0.5, b=0.5, black=0.0, global_max=1.0, coherent=False, steps=12, f_hi=48):
    """N-step stacks (steps, n_px) of the unit and a high frequency at ``n_px`` camera pixels: each
    sees its own projector column (direct reflectance d) plus global light gathered smoothly (a Hann
    window) from a run of other columns 10-50 % of the width long (total weight up to
    ``global_max`` x d), as a wall lit across a stretch of the pattern returns it; the pattern is
    ``a + b cos``. Returns the stacks, the direct unit phase and the planted global / direct ratio."""
    x = rng.uniform(0, 1, n_px)                           # projector column (fraction of the width)
    d = rng.uniform(0.3, 1.0, n_px)
    t = np.linspace(0, 1, 400)[:, None]
    src = (x + rng.uniform(0.05, 0.9, n_px) + rng.uniform(0.1, 0.5, n_px) * t) % 1.0
    k = np.broadcast_to(np.sin(np.pi * t) ** 2, src.shape).copy()
    if coherent:               # from a run 10 % of the width long (4.8 periods at 48), a quarter period away
        src = (x + 0.2 + 0.1 * t) % 1.0
    k *= (rng.uniform(0, global_max, n_px) * d / k.sum(0))
    shifts = TWO_PI * np.arange(steps) / steps
    stacks = {}
    for f in (1, f_hi):
        s = np.empty((steps, n_px))
        for i, dl in enumerate(shifts):
            s[i] = black + d * (a + b * np.cos(TWO_PI * f * x - dl)) + (k * (a + b * np.cos(TWO_PI * f * src - dl))).sum(0)
        stacks[f] = s
    return stacks, wrap(TWO_PI * x), k.sum(0) / d


def test_the_separation_recovers_the_planted_global_ratio_and_the_bound_holds():
    rng = np.random.default_rng(0)
    stacks, phi_direct, rho_true = _capture(rng, 4000, black=0.0)
    w1, wh = (wrapped_phase(stacks[f][:, None, :], saturation=None) for f in (1, 48))
    g = bias_bound(wh.A, wh.B, np.ones((1, 4000), bool), kappa=1.0, offset_low=w1.A)
    # at f = 48 the 40 random source columns average out to within a few % of the direct modulation
    assert np.abs(g.ratio[0] - rho_true).max() < 0.1 * rho_true.max()
    bias = np.abs(wrap(w1.phase[0] - phi_direct))
    assert np.all(bias <= g.bound_rad[0] + 0.02)          # never beyond the bound (+ the residual above)
    assert g.notes == []                                   # A_1 = A_h: the frequencies were captured alike
    g1 = bias_bound(wh.A, wh.B, np.ones((1, 4000), bool), kappa=1.0, modulation_low=w1.B)
    assert np.all(g1.bound_rad <= g.bound_rad + 1e-12) and np.all(bias <= g1.bound_rad[0] + 0.02)


def test_the_unit_modulation_tightens_the_bound_under_blur_and_it_still_holds():
    rng = np.random.default_rng(4)
    stacks, phi_direct, _ = _capture(rng, 3000, global_max=0.4)
    m = rng.uniform(0.3, 1.0, 3000)                       # blur keeps a fraction m of the high modulation
    mean = stacks[48].mean(0)
    stacks[48] = mean + m * (stacks[48] - mean)
    w1, wh = (wrapped_phase(stacks[f][:, None, :], saturation=None) for f in (1, 48))
    ones = np.ones((1, 3000), bool)
    g0 = bias_bound(wh.A, wh.B, ones, kappa=1.0)
    g1 = bias_bound(wh.A, wh.B, ones, kappa=1.0, modulation_low=w1.B)
    bias = np.abs(wrap(w1.phase[0] - phi_direct))
    assert np.all(bias <= g1.bound_rad[0] + 0.02)
    assert np.median(g1.bound_rad) < 0.7 * np.median(g0.bound_rad)
    # blurred pixels the high frequency alone calls "global >= direct" (bound pi) are mostly bounded
    assert (g1.bound_rad == math.pi).mean() < 0.2 * (g0.bound_rad == math.pi).mean()


def test_a_coherent_global_phasor_at_right_angles_reaches_the_bound():
    rng = np.random.default_rng(1)
    stacks, phi_direct, rho_true = _capture(rng, 2000, global_max=0.6, coherent=True)
    w1, wh = (wrapped_phase(stacks[f][:, None, :], saturation=None) for f in (1, 48))
    g = bias_bound(wh.A, wh.B, np.ones((1, 2000), bool), kappa=1.0)
    bias = np.abs(wrap(w1.phase[0] - phi_direct))
    # a quarter period away: the global phasor is (nearly: the run's own phase spread) perpendicular to
    # the direct one, the bias ~atan(rho)
    assert bias == pytest.approx(np.arctan(rho_true), abs=0.03)
    assert np.all(bias <= g.bound_rad[0] + 0.02)
    assert np.median(bias / np.maximum(g.bound_rad[0], 1e-9)) > 0.8     # the bound is nearly tight here


def test_kappa_is_estimated_from_the_least_lit_by_global_light_and_black_is_subtracted():
    rng = np.random.default_rng(2)
    # the pattern 0.45 + 0.3 cos (kappa 1.5: a projector black level), a black level of 0.02,
    # 20 % of the pixels without global light
    stacks, _, _ = _capture(rng, 5000, a=0.45, b=0.3, black=0.02)
    wh = wrapped_phase(stacks[48][:, None, :], saturation=None)
    A, B = wh.A.copy(), wh.B
    none = rng.uniform(size=5000) < 0.2
    A[0, none] = 0.02 + 1.5 * B[0, none]
    k = pattern_offset_ratio(A, B, np.ones_like(A, bool), black=0.02)
    assert k == pytest.approx(1.5, abs=0.03)
    g = bias_bound(A, B, np.ones_like(A, bool), black=0.02)
    assert g.kappa_source.startswith("estimated") and g.ratio[0, none].max() < 0.03
    # ignoring the black level counts it as global light: the ratio (and the bound) only grow
    g0 = bias_bound(A, B, np.ones_like(A, bool), kappa=1.5)
    assert np.all(g0.ratio >= g.ratio - 1e-12)


def test_nonsense_captures_are_refused_or_flagged():
    ones = np.ones((40, 40), bool)
    with pytest.raises(GlobalLightError, match="outside"):            # A far below B: not a sinusoid
        bias_bound(np.full((40, 40), 1.0), np.full((40, 40), 50.0), ones)
    with pytest.raises(GlobalLightError, match="too few"):
        pattern_offset_ratio(np.ones((10, 10)), np.ones((10, 10)), np.ones((10, 10), bool))
    with pytest.raises(GlobalLightError, match="one \\(H, W\\) shape"):
        bias_bound(np.ones((4, 4)), np.ones((4, 5)), np.ones((4, 4), bool), kappa=1.0)
    with pytest.raises(GlobalLightError, match="kappa"):
        bias_bound(np.ones((4, 4)), np.ones((4, 4)), np.ones((4, 4), bool), kappa=-1.0)
    g = bias_bound(np.full((40, 40), 60.0), np.full((40, 40), 50.0), ones, kappa=1.0,
                   offset_low=np.full((40, 40), 90.0))              # the unit frame 1.5x brighter
    assert g.notes and "not captured alike" in g.notes[0]
    # a global ratio >= 1 can turn the phase anywhere; invalid pixels carry 0
    v = ones.copy()
    v[0, 0] = False
    g = bias_bound(np.full((40, 40), 120.0), np.full((40, 40), 50.0), v, kappa=1.0)
    assert g.bound_rad[1, 1] == pytest.approx(math.pi) and g.bound_rad[0, 0] == 0.0
    assert g.fringes(1, 48)[1, 1] == pytest.approx(24.0)


def test_the_data_term_without_a_bound_is_the_shipped_one_and_widens_with_it():
    rng = np.random.default_rng(3)
    prior = rng.uniform(2, 40, (20, 30))
    order = np.rint(prior).astype(np.int64)
    valid = rng.uniform(size=prior.shape) > 0.1
    c0 = prior_data_cost(prior, order, 0.05, valid, frequency_high=48, outlier=0.2)
    assert np.array_equal(c0, prior_data_cost(prior, order, 0.05, valid, frequency_high=48, outlier=0.2,
                                              bias_sigma=None))
    assert np.array_equal(c0, prior_data_cost(prior, order, 0.05, valid, frequency_high=48, outlier=0.2,
                                              bias_sigma=0.0))
    c1 = prior_data_cost(prior, order, 0.05, valid, frequency_high=48, outlier=0.2, bias_sigma=1.0)
    # the cost of the best other order over the rounded one shrinks where the bias may be large
    sure = valid & (np.abs(prior - order) < 0.1)           # within 2 sigma of its order: a confident term
    gap = lambda c: np.sort(c, axis=0)[1][sure]           # noqa: E731  (min is 0 at the rounded order)
    assert np.all(gap(c1) < gap(c0))


def _band_scene(bias_fringes=0.93):
    """MF (1, 16), 1024-px pattern, a smooth surface beside an invalid strip (a shadow) with a
    biased band 24 px wide along it: the band's prior sits ``bias_fringes`` off, every pixel of it
    rounds to the wrong order, and its global / direct ratio is high, elsewhere ~0."""
    H, W, f, width = 90, 160, 16, 1024
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    u = 150 + 3.2 * x + 0.6 * y
    valid = x >= 6                                        # the shadow on the left
    band = valid & (x < 30)
    Phi = lambda f: TWO_PI * f * u / width               # noqa: E731
    lo = wrap(Phi(1) + np.where(band, bias_fringes * TWO_PI / f, 0.0))
    hi = wrap(Phi(f))
    k_true = np.rint((Phi(f) - hi) / TWO_PI).astype(np.int64)
    ratio = np.where(band, 0.6, 0.01)                    # global / direct
    bound = np.where(ratio < 1, np.arcsin(np.minimum(ratio, 1)), math.pi) * f / TWO_PI
    return lo, hi, k_true, band, valid, bound, (1, f), width


def test_the_bound_lets_the_surface_bring_back_a_biased_band_the_shipped_term_keeps():
    lo, hi, k_true, band, valid, bound, freqs, width = _band_scene()
    r0 = graphcut_orders("mf", lo, hi, freqs, valid, 0.01, 0.01, width=width, bias_bound=None)
    assert (r0.order_traditional != k_true)[band].mean() > 0.99
    assert (r0.order != k_true)[band].mean() > 0.9        # band area x data cost beats its boundary
    r1 = graphcut_orders("mf", lo, hi, freqs, valid, 0.01, 0.01, width=width, bias_bound=bound, bias_scale=1.0)
    assert (r1.order != k_true)[valid].mean() < 0.001     # the band joins its surface
    assert np.array_equal(r0.order_traditional, r1.order_traditional)


def test_calib_unwrap_spatial_global_bound_on_a_clean_capture(tmp_path, capsys):
    """``--global-bound`` on a clean rendered capture (tests/test_cli_bad_inputs.py's): the global /
    direct ratio is written, and with little global light the graph cut keeps the (right)
    traditional orders; the flag is refused where it does not apply."""
    import h5py

    from sltwin.cli import main
    from test_cli_bad_inputs import _write_capture

    _write_capture(tmp_path / "cap")
    assert main(["unwrap", str(tmp_path / "cap"), "--spatial", "graphcut", "--global-bound", "--no-gate",
                 "-o", str(tmp_path / "gb"), "--no-previews", "-q"]) == 0
    with h5py.File(tmp_path / "gb" / "unwrap.h5") as b:
        for o in ("v", "h"):
            g = b[o]
            assert g.attrs["method"] == "mf+graphcut+global"
            ok = g["valid"][()]
            assert ok.mean() > 0.9 and np.all(g["global_ratio"][()][ok] >= 0)
            assert np.array_equal(g["order"][()], g["order_traditional"][()])
    for bad in (["--global-bound"], ["--spatial", "graphcut", "--global-bound", "--model", "learned"],
                ["--spatial", "graphcut", "--global-bound", "--method", "nt"],
                ["--spatial", "graphcut", "--global-bound", "--method", "mw"],
                ["--spatial", "graphcut", "--global-bound", "--method", "gray"]):
        capsys.readouterr()
        assert main(["unwrap", str(tmp_path / "cap"), *bad, "-o", str(tmp_path / "x"), "--no-previews", "-q"]) == 2
        err = capsys.readouterr().err
        assert "--global-bound belongs to --spatial graphcut" in err and "Traceback" not in err, bad
    assert not (tmp_path / "x").exists()


def test_the_decision_error_model_with_the_global_ratio_is_monotone_and_checked():
    from unwrap.decision_error import MODEL, MODEL_GLOBAL, error_probability
    from unwrap.errors import UnwrapError

    H, W = 40, 60
    valid = np.ones((H, W), bool)
    valid[:, :3] = False
    prior = np.full((H, W), 7.0)
    args = (np.full((H, W), 1e-6), prior, valid, np.full((H, W), 0.3), np.full((H, W), 0.3))
    p_lo = error_probability(*args, global_ratio=np.full((H, W), 0.05))
    p_hi = error_probability(*args, global_ratio=np.full((H, W), 0.8))
    assert np.all(p_hi[valid] >= p_lo[valid]) and (p_hi[valid] > p_lo[valid]).any()
    assert np.all(p_lo[~valid] == 0)
    with pytest.raises(UnwrapError, match="global_ratio exactly"):
        error_probability(*args, model=MODEL, global_ratio=np.zeros((H, W)))
    with pytest.raises(UnwrapError, match="global_ratio exactly"):
        error_probability(*args, model=MODEL_GLOBAL)
    with pytest.raises(UnwrapError, match="global_ratio"):
        error_probability(*args, global_ratio=np.zeros((H, W + 1)))


def test_a_nan_or_inf_offset_or_modulation_at_a_valid_pixel_gets_the_bound_pi_not_zero():
    A, B = np.full((30, 30), 50.0), np.full((30, 30), 50.0)      # no global light: bound 0
    A[0, 0], B[0, 1], B[0, 2], A[0, 3] = np.nan, np.inf, np.nan, np.inf
    B1 = np.full((30, 30), 50.0)
    B1[1, 0] = np.inf                                             # a non-finite unit modulation: B_h alone
    ones = np.ones((30, 30), bool)
    for g in (bias_bound(A, B, ones, kappa=1.0), bias_bound(A, B, ones, kappa=1.0, modulation_low=B1),
              bias_bound(A, B, ones)):                            # kappa estimated from the finite pixels
        assert np.all(g.bound_rad[0, :4] == pytest.approx(math.pi)) and np.all(np.isfinite(g.ratio))
        assert g.bound_rad[1, 0] == 0.0 and g.bound_rad[5, 5] == 0.0
    A[0, 5] = 70.0                                                # rho 0.4 with B_1 at inf: asin(0.4), not 0
    B1[0, 5] = np.inf
    assert bias_bound(A, B, ones, kappa=1.0, modulation_low=B1).bound_rad[0, 5] == pytest.approx(math.asin(0.4))


def test_the_bound_is_refused_where_it_cannot_act_instead_of_being_ignored(tmp_path):
    from test_cli_bad_inputs import _write_capture

    from unwrap.errors import UnwrapError
    from unwrap.spatial_capture import unwrap_capture_spatial

    lo, hi, _, _, valid, bound, freqs, width = _band_scene()
    cost = np.zeros((5,) + lo.shape)
    with pytest.raises(UnwrapError, match="given cost"):
        graphcut_orders("mf", lo, hi, freqs, valid, 0.01, 0.01, width=width, cost=cost, bias_bound=bound)
    _write_capture(tmp_path / "cap")
    with pytest.raises(UnwrapError, match="method 'nt'"):
        unwrap_capture_spatial(tmp_path / "cap", "nt", global_bound=True)


def test_the_bias_spread_adds_to_the_prior_sigma_in_quadrature_and_a_zero_bound_changes_no_order():
    rng = np.random.default_rng(5)
    prior = rng.uniform(2, 40, (20, 30))
    order = np.rint(prior).astype(np.int64)
    valid = rng.uniform(size=prior.shape) > 0.1
    sigma, b = rng.uniform(0.02, 0.2, prior.shape), rng.uniform(0.0, 1.5, prior.shape)
    c = prior_data_cost(prior, order, sigma, valid, frequency_high=48, outlier=0.2, bias_sigma=b)
    ref = prior_data_cost(prior, order, np.hypot(sigma, b), valid, frequency_high=48, outlier=0.2)
    assert np.allclose(c, ref, rtol=1e-12, atol=1e-12)
    lo, hi, _, _, valid, bound, freqs, width = _band_scene()
    r0 = graphcut_orders("mf", lo, hi, freqs, valid, 0.01, 0.01, width=width)
    rz = graphcut_orders("mf", lo, hi, freqs, valid, 0.01, 0.01, width=width, bias_bound=np.zeros_like(bound))
    assert np.array_equal(r0.order, rz.order)
    from unwrap.errors import UnwrapError
    with pytest.raises(UnwrapError, match="bias_scale"):
        graphcut_orders("mf", lo, hi, freqs, valid, 0.01, 0.01, width=width, bias_bound=bound, bias_scale=-1.0)


def test_a_refused_separation_falls_back_to_the_plain_term_with_a_warning(caplog):
    from types import SimpleNamespace

    from unwrap.spatial_capture import global_bias_bound

    ones = np.ones((40, 40), bool)
    lo = SimpleNamespace(A=np.full((40, 40), 1.0), B=np.full((40, 40), 50.0))
    hi = SimpleNamespace(A=np.full((40, 40), 1.0), B=np.full((40, 40), 50.0))   # A << B: kappa 0.02, refused
    with caplog.at_level("WARNING"):
        assert global_bias_bound(lo, hi, ones, "mf", (1.0, 16.0), "v") == (None, None)
    assert "no global-light bound" in caplog.text and "outside" in caplog.text
    hi.A = np.full((40, 40), 60.0)                                                # kappa 1.2: a bound
    bound, ratio = global_bias_bound(lo, hi, ones, "mf", (1.0, 16.0), "v")
    assert bound.shape == (40, 40) and np.all(ratio == 0.0) and np.all(bound == 0.0)
