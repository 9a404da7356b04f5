"""Temporal unwrapping: exact k on noise-free stacks for every method, hard cases, float32 vs float64."""
import math
import warnings

import numpy as np
import pytest

from unwrap import (UnreliableFringesWarning, UnwrapError, complementary_gray_unwrap,
                    gray_coarse_unwrap, gray_code_bits, gray_to_index, gray_unwrap, mf_unwrap,
                    mw_unwrap, nt_lookup_table, nt_unwrap, wrapped_phase)
from unwrap.patterns import absolute_phase, fringe_pattern

W_P, H_P = 912, 1140  # the paper's projector


def _wrapped(f, orientation="v", steps=12, offset=0.0, reverse=False):
    """Wrapped phase of a noise-free stack made by the pattern generator (one row/column)."""
    size = (W_P, 2) if orientation == "v" else (2, H_P)
    frames = []
    for n in range(steps):
        step = (steps - n) % steps if reverse else n
        img = fringe_pattern(size, f, step, steps, orientation, A=0.5, B=0.45)
        frames.append(img[0] if orientation == "v" else img[:, 0])
    stack = np.stack(frames)
    if offset:
        extent = W_P if orientation == "v" else H_P
        coord = np.arange(extent, dtype=np.float64)
        Phi = absolute_phase(coord, f, extent) + offset
        stack = np.stack([0.5 + 0.45 * np.cos(Phi - 2 * np.pi * n / steps) for n in range(steps)])
    return wrapped_phase(stack).phase


def _truth(f, orientation="v"):
    extent = W_P if orientation == "v" else H_P
    return absolute_phase(np.arange(extent, dtype=np.float64), f, extent)


def _assert_exact(res, f, orientation, phases_hi):
    Phi = _truth(f, orientation)
    k_true = np.round((Phi - phases_hi) / (2 * np.pi)).astype(np.int32)
    assert res.valid.all()
    np.testing.assert_array_equal(res.order, k_true)
    assert np.abs(res.phase - Phi).max() < 1e-9
    assert res.phase.dtype == np.float64 and res.order.dtype == np.int32


MF_LADDERS = [(1, 8, 48), (1, 4, 16, 64), (1, 12, 96), (1, 8, 64, 192), (1, 16, 128, 384)]


@pytest.mark.parametrize("orientation", ["v", "h"])
@pytest.mark.parametrize("ladder", MF_LADDERS)
def test_mf_exact_on_noise_free_stack_up_to_96_periods_and_beyond(ladder, orientation):
    phases = [_wrapped(f, orientation) for f in ladder]
    extent = W_P if orientation == "v" else H_P
    res = mf_unwrap(phases, ladder, width=extent)
    _assert_exact(res, ladder[-1], orientation, phases[-1])
    assert np.abs(res.prior - res.order).max() < 1e-9  # noise-free prior is the integer k


@pytest.mark.parametrize("freqs", [(48, 47), (96, 95), (192, 191), (384, 383), (70, 64, 59), (96, 90, 85)])
def test_mw_exact_on_noise_free_stacks(freqs):
    phases = [_wrapped(f) for f in freqs]
    res = mw_unwrap(phases, freqs, width=W_P)
    _assert_exact(res, max(freqs), "v", phases[int(np.argmax(freqs))])


def test_mw_accepts_pitches_that_do_not_divide_the_width():
    pitches = (57.0, 60.0)  # 16 and 15.2 periods across 912 px: beat 0.8
    phases = [_wrapped(W_P / p) for p in pitches]
    res = mw_unwrap(phases, pitches=pitches, width=W_P)
    assert res.frequency == pytest.approx(16.0)
    _assert_exact(res, 16.0, "v", phases[0])
    frac = (13.7, 14.3)  # neither divides 912 (beat 912/13.7 - 912/14.3 = 2.79 > 1: refused)
    with pytest.raises(UnwrapError, match="beat frequency is 2.79"):
        mw_unwrap([_wrapped(W_P / p) for p in frac], pitches=frac, width=W_P)


@pytest.mark.parametrize("pair", [(47, 48), (95, 96), (7, 96), (96, 97), (127, 128), (383, 384)])
def test_nt_exact_on_noise_free_stacks(pair):
    phases = [_wrapped(f) for f in pair]
    res = nt_unwrap(phases, pair, width=W_P)
    _assert_exact(res, max(pair), "v", phases[int(np.argmax(pair))])
    assert np.allclose(res.prior, np.round(res.prior), atol=1e-9)


def test_nt_lookup_table_is_built_once_per_pair():
    nt_lookup_table.cache_clear()
    for _ in range(3):
        nt_unwrap([_wrapped(47), _wrapped(48)], (47, 48))
    info = nt_lookup_table.cache_info()
    assert info.misses == 1 and info.hits == 2


def test_a_constant_phase_offset_or_a_step_sign_mistake_fails_exactness():
    good = [_wrapped(f) for f in (1, 8, 48)]
    assert np.abs(mf_unwrap(good, (1, 8, 48), width=W_P).phase - _truth(48)).max() < 1e-9
    off = [_wrapped(f, offset=0.2) for f in (1, 8, 48)]
    assert np.nanmax(np.abs(mf_unwrap(off, (1, 8, 48), width=W_P).phase - _truth(48))) > 0.19
    rev = [_wrapped(f, reverse=True) for f in (1, 8, 48)]
    r = mf_unwrap(rev, (1, 8, 48), width=W_P)
    assert (~r.valid).any() or np.nanmax(np.abs(r.phase - _truth(48))) > 1.0


def test_gray_code_with_one_block_per_period_is_exact_noise_free():
    f = 32
    u = np.arange(W_P, dtype=np.float64)
    c = gray_to_index(gray_code_bits(np.floor(u * f / W_P).astype(int), 5))
    res = gray_unwrap(_wrapped(f), c, f)
    _assert_exact(res, f, "v", _wrapped(f))


def test_complementary_gray_code_is_exact_even_with_code_edges_misplaced_by_an_eighth_period():
    f = 32
    P = W_P / f
    u = np.arange(W_P, dtype=np.float64)
    phi = _wrapped(f)
    for shift in (0.0, P / 8, -P / 8):
        K1 = gray_to_index(gray_code_bits(np.clip(np.floor((u + shift) / P), 0, 31).astype(int), 5))
        G = gray_to_index(gray_code_bits(np.clip(np.floor((u + shift) / (P / 2)), 0, 63).astype(int), 6))
        res = complementary_gray_unwrap(phi, K1, (G + 1) // 2, f)
        _assert_exact(res, f, "v", phi)


def test_gray_blocks_plus_beat_phase_are_exact_with_misplaced_code_edges():
    """kamino410 layout: 100 px Gray blocks, fringes of 100 and 66.7 px, beat 200 px."""
    width = 1920.0
    u = np.arange(1920, dtype=np.float64)
    f_lo, f_hi = width / 100, width / (200 / 3)
    phi = {f: np.angle(np.exp(1j * absolute_phase(u, f, width))) for f in (f_lo, f_hi)}
    beat = np.angle(np.exp(1j * (phi[f_hi] - phi[f_lo])))
    for shift in (0.0, 20.0, -20.0):
        c = np.clip(np.floor((u + shift) / 100), 0, 19)
        res = gray_coarse_unwrap(c, 100, width, [beat, phi[f_hi]], [f_hi - f_lo, f_hi])
        assert res.valid.all()
        assert np.abs(res.phase - absolute_phase(u, f_hi, width)).max() < 1e-9


def test_mf_unwrap_runs_on_torch_tensors():
    torch = pytest.importorskip("torch")
    phases = [torch.tensor(_wrapped(f)) for f in (1, 8, 48)]
    res = mf_unwrap(phases, (1, 8, 48), width=W_P)
    assert torch.is_tensor(res.phase) and res.order.dtype == torch.int32
    assert float((res.phase - torch.tensor(_truth(48))).abs().max()) < 1e-9
    res = mw_unwrap([torch.tensor(_wrapped(f)) for f in (96, 95)], (96, 95), width=W_P)
    assert float((res.phase - torch.tensor(_truth(96))).abs().max()) < 1e-9


def test_non_coprime_nt_pairs_are_refused():
    with pytest.raises(UnwrapError, match="share the factor 16"):
        nt_unwrap([_wrapped(48), _wrapped(64)], (48, 64))
    with pytest.raises(UnwrapError, match="integers"):
        nt_unwrap([_wrapped(48), _wrapped(47)], (48.5, 47))


def test_mf_ladder_with_too_large_a_ratio_warns_or_refuses_with_the_predicted_error_rate():
    phases = [_wrapped(f) for f in (1, 96)]
    with pytest.warns(UnreliableFringesWarning, match=r"predicted fringe-order error rate 0\.\d+"):
        mf_unwrap(phases, (1, 96), phase_sigma=0.02)
    with pytest.raises(UnwrapError, match="exceeds the limit"):
        mf_unwrap(phases, (1, 96), phase_sigma=0.02, on_unreliable="raise")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the paper's ladder at the same noise is fine
        mf_unwrap([_wrapped(f) for f in (1, 8, 48)], (1, 8, 48), phase_sigma=0.02)


@pytest.mark.parametrize("call, msg", [
    (lambda p: mf_unwrap(p[:1], (1,)), "at least two"),
    (lambda p: mf_unwrap(p, (8, 48, 1)), "increase strictly"),
    (lambda p: mf_unwrap(p, (4, 8, 48)), "lowest frequency <= 1"),
    (lambda p: mf_unwrap(p, (1, 8)), "3 wrapped phases but 2 frequencies"),
    (lambda p: mf_unwrap([p[0], p[1][:10], p[2]], (1, 8, 48)), "shape"),
    (lambda p: mw_unwrap(p[1:], (8, 48)), "beat frequency is 40"),
    (lambda p: mw_unwrap(p, (1, 8, 48, 49)[:3], pitches=(1, 2, 3)), "either frequencies"),
])
def test_bad_unwrapping_inputs_are_clear_errors(call, msg):
    p = [_wrapped(f) for f in (1, 8, 48)]
    with pytest.raises(UnwrapError, match=msg):
        call(p)


def test_nan_phase_pixels_come_out_invalid_not_garbage():
    phases = [_wrapped(f) for f in (1, 8, 48)]
    phases[1][100:110] = np.nan
    res = mf_unwrap(phases, (1, 8, 48), width=W_P)
    assert not res.valid[100:110].any() and (res.order[100:110] == -1).all()
    assert np.isnan(res.phase[100:110]).all() and res.valid.sum() == W_P - 10


def test_float32_breaks_where_its_phase_resolution_exceeds_the_quantisation_noise():
    """float32 absolute phase carries ~eps32 * 2 pi f rad: above the 16-bit noise floor already at
    ~10 periods, above the 8-bit one near 2500 periods; float64 stays below 1e-9 rad at 4096."""
    out = {}
    for f in (48, 96, 384, 4096):
        W = 65536  # long virtual projector, pixel centres at integers
        u = np.arange(0, W, 7, dtype=np.float64)
        Phi = absolute_phase(u, f, W)
        phi64 = np.angle(np.exp(1j * Phi))
        k = np.round((Phi - phi64) / (2 * np.pi))
        Phi32 = phi64.astype(np.float32) + np.float32(2 * np.pi) * k.astype(np.float32)
        Phi64 = phi64 + 2 * np.pi * k
        out[f] = (np.abs(Phi32.astype(np.float64) - Phi).max(), np.abs(Phi64 - Phi).max())
    sigma_16bit = math.sqrt(2 / 12) * (1 / math.sqrt(12)) / 32767  # 12-step, full-range 16-bit
    sigma_8bit = math.sqrt(2 / 12) * (1 / math.sqrt(12)) / 127.5
    assert all(e64 < 1e-9 for _, e64 in out.values())
    assert out[96][0] > sigma_16bit and out[96][0] > 1e4 * out[96][1]
    assert out[96][0] < sigma_8bit < out[4096][0]


def test_half_integer_prior_is_a_tie_resolved_down_identically_on_every_path():
    """A prior within 1e-9 of a half integer goes to the lower order (numpy, torch and the fused
    kernel alike), so the last bit of the prior - which BLAS kernels, FMA and thread counts
    change - never decides the order (issue 15, item 1: 2.4999999999999996 vs 2.5000000000000004)."""
    import torch

    from unwrap._fused_kernel import _refine
    from unwrap._xp import TIE_BAND, round_order
    from unwrap.temporal import refine
    below, above = np.nextafter(2.5, 0.0), np.nextafter(2.5, 3.0)
    prior = np.array([2.4, below, 2.5, above, 2.5 + 0.5 * TIE_BAND, 2.5 + 3 * TIE_BAND,
                      -0.5, 3.5, 95.5, np.nextafter(95.5, 96.0), 0.0])
    expect = np.array([2, 2, 2, 2, 2, 3, -1, 3, 95, 95, 0], dtype=float)
    assert np.array_equal(round_order(prior), expect)
    assert np.array_equal(round_order(torch.from_numpy(prior)).numpy(), expect)
    # the kernel's eq. 7 step, fed a coarse phase that puts the prior on the same values
    Phi_s = prior * 2.0 * np.pi
    pr_s, k_s = np.empty_like(prior), np.empty_like(prior)
    _refine(np.zeros_like(prior), 1.0, Phi_s.copy(), pr_s, k_s)
    _, k_ref, _ = refine(prior * 2.0 * np.pi, 1.0, np.zeros_like(prior))
    assert np.array_equal(k_s, k_ref)
    assert np.abs(k_ref - expect).max() <= 1   # prior * 2 pi / 2 pi may move a value by an ulp
