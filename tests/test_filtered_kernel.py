"""The compiled filtered baseline (unwrap.learned._filtered_kernel around the plane kernel) gives
exactly the orders of the numpy formulation (baselines._filtered_order_numpy), every pixel."""
from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import shared_data

pytest.importorskip("numba")


def _both(method, lo, hi, freqs, valid, width=912, window=15):
    from unwrap.learned.baselines import _filtered_order_numpy, filtered_order

    got = filtered_order(method, lo, hi, freqs, valid, window=window, width=width)
    ref = _filtered_order_numpy(method, lo, hi, float(freqs[0]), float(freqs[1]), np.asarray(valid, bool),
                                window, "plane", width)
    return got, ref


def _damage(s, valid, seed):
    """NaNs and infs in the phases (some inside ``valid``), a block and scattered pixels invalid."""
    rng = np.random.default_rng(seed)
    lo, hi = np.array(s["phase_low"], np.float64), np.array(s["phase_high"], np.float64)
    H, W = lo.shape
    for a, bad in ((lo, np.nan), (hi, np.nan), (lo, np.inf), (hi, -np.inf)):
        a[rng.integers(0, H, 40), rng.integers(0, W, 40)] = bad
    valid = valid.copy()
    valid[H // 3:H // 3 + 20, W // 4:W // 4 + 30] = False
    valid[rng.random((H, W)) < 0.05] = False
    # valid pixels whose coarse phase is no wrapped phase: the MW / NT beat of (-inf, inf) is NaN,
    # an MF low phase of 20 rad lies outside the cut's 2 pi
    ys, xs = rng.integers(0, H, 10), rng.integers(0, W, 10)
    lo[ys, xs], hi[ys, xs], valid[ys, xs] = -np.inf, np.inf, True
    ys, xs = rng.integers(0, H, 10), rng.integers(0, W, 10)
    lo[ys, xs], valid[ys, xs] = 20.0, True
    return lo, hi, valid


@pytest.mark.parametrize("method,freqs", [("mf", (1, 48)), ("mf", (1, 16)), ("mw", (47, 48)), ("nt", (47, 48)),
                                          ("nt", (95, 96))])
@pytest.mark.parametrize("index", [1, 4])
def test_compiled_filtered_order_equals_the_numpy_formulation(method, freqs, index):
    from unwrap.learned.synthetic import synthetic_sample

    s = synthetic_sample(index, size=(96, 130), method=method, frequencies=freqs)
    valid = np.asarray(s["valid"], bool)
    lo, hi, valid = _damage(s, valid, index)
    for width, window in ((912, 15), (None, 7)):
        got, ref = _both(method, lo, hi, freqs, valid, width, window)
        assert got.dtype == np.int64 and got.shape == ref.shape
        assert np.array_equal(got, ref)
        assert (got >= 0).sum() > 3000 and (got == -1).sum() > 500        # both kinds of pixel present
    # those take the numpy fix-up of the coarse pass
    from unwrap.learned import _filtered_kernel as FK
    assert FK.coarse_kernel(lo, hi, valid, method == "mf", -0.1, np.empty(lo.shape)) > 0
    # float32 phases and a non-contiguous valid mask go through the same kernels
    got, ref = _both(method, lo.astype(np.float32), hi.astype(np.float32), freqs, np.asfortranarray(valid))
    assert np.array_equal(got, ref)


def test_compiled_filtered_order_near_rounding_boundaries():
    """Phases built so that many priors sit on or next to a half order: the tie rule must agree."""
    H, W = 40, 90
    u = np.tile(np.arange(W, dtype=np.float64), (H, 1)) * 0.5 + 100.0
    f_lo, f_hi = 1.0, 48.0
    Phi = 2 * np.pi * f_lo * u / 912
    hi = np.angle(np.exp(1j * (2 * np.pi * f_hi * u / 912))) + np.pi * (np.arange(W) % 2)  # pi jumps
    hi = np.angle(np.exp(1j * hi))
    lo = np.angle(np.exp(1j * Phi))
    valid = np.ones((H, W), bool)
    got, ref = _both("mf", lo, hi, (f_lo, f_hi), valid)
    assert np.array_equal(got, ref) and (got >= 0).all()


@pytest.mark.realdata
def test_compiled_filtered_order_on_a_real_capture():
    from unwrap.capture import load_capture, read_stack
    from unwrap.phase_shift import wrapped_phase

    oc = load_capture(shared_data("slstudio-ps2x3-calib") / "skull_2x3").orientations["v"]
    sets = sorted(oc.sets, key=lambda s: s.frequency)
    wp = [wrapped_phase(read_stack(s.files), s.shifts, min_modulation=0.02 * 255) for s in sets]
    valid = np.asarray(wp[0].valid, bool) & np.asarray(wp[1].valid, bool)
    freqs = (sets[0].frequency, sets[1].frequency)
    got, ref = _both("mf", wp[0].phase, wp[1].phase, freqs, valid, width=oc.width)   # NaN outside valid
    assert np.array_equal(got, ref)
    assert (got >= 0).sum() > 80_000 and (got == -1).sum() > 1000
