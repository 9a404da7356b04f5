"""The fused MF kernel (unwrap.fused_mf) gives the reference's k and masks exactly, its phase within 1e-12 rad."""
import math

import numpy as np
import pytest

from tests.conftest import shared_data
from unwrap import UnwrapError
from unwrap.fused_mf import factor_weights, fast_available, mf_unwrap_stacks
from unwrap.patterns import absolute_phase, fringe_intensity
from unwrap.phase_shift import equal_shifts, least_squares_weights

pytestmark = pytest.mark.skipif(not fast_available(), reason="numba not installed")

W_P = 912
PHASE_TOL = 1e-12  # rad


def _scene(H=48, W=160, seed=0):
    """Projector column per camera pixel plus per-pixel A, B with the hard cases in bands of rows."""
    rng = np.random.default_rng(seed)
    u = np.linspace(-0.3, W_P - 0.7, W)[None, :].repeat(H, 0)  # both ends of the pattern
    A = np.full((H, W), 120.0)
    B = np.full((H, W), 90.0)
    B[4:8] = rng.uniform(0.0, 8.0, (4, W))      # low modulation around min_modulation = 5.1
    B[8:10] = 0.0                               # flat: phase undefined
    A[10:12], B[10:12] = 200.0, 90.0             # saturates near the fringe crests
    A[12:13], B[12:13] = 255.0, 0.0              # flat white
    A[13:14], B[13:14] = 0.0, 0.0                # flat black
    A[14:16], B[14:16] = 20.0, 40.0              # clipped at 0 (valid_range tests)
    return u, A, B, rng


def _stacks(freqs, steps, dtype=np.uint8, sigma=2.0, seed=0, scale=1.0, shifts=None):
    u, A, B, rng = _scene(seed=seed)
    top = np.iinfo(dtype).max
    out = []
    for f, N in zip(freqs, steps):
        Phi = absolute_phase(u, f, W_P)
        if shifts is None:
            frames = [fringe_intensity(Phi, n, N, A=A, B=B) for n in range(N)]
        else:
            frames = [A + B * np.cos(Phi - d) for d in shifts]
        noise = rng.normal(0.0, sigma * scale, (len(frames),) + u.shape)
        noise[:, 8:10] = noise[:, 12:14] = 0.0   # exactly flat rows
        st = scale * np.stack(frames) + noise
        out.append(np.clip(np.round(st), 0, top).astype(dtype))
    return out


def _cut_ties(k_fast, k_ref, prior_fast, prior_ref, Phi_ref):
    """Pixels where k differs, checked to be ties at the wrapped phase's +-pi cut.

    Where the least-squares sine sum is exactly 0 and the cosine sum negative, the phase is pi;
    the kernel's integer sums give exactly 0 (phase +pi) while the reference's BLAS rounding
    leaves +-4e-15 (phase -pi or pi). Both then describe the same absolute phase with k one
    apart and the prior exactly one apart."""
    differ = k_fast != k_ref
    if differ.any():
        assert np.all(np.abs(k_fast[differ] - k_ref[differ]) == 1)
        assert np.all(np.abs(np.abs(prior_fast[differ] - prior_ref[differ]) - 1.0) <= PHASE_TOL)
        phi_ref = Phi_ref[differ] - 2 * np.pi * k_ref[differ]
        assert np.all(np.abs(phi_ref) > np.pi - 1e-9)
    return int(differ.sum())


def _assert_same(fast, ref, levels=False):
    """Returns the number of +-pi cut ties (see _cut_ties); everything else must agree."""
    assert fast.fast and not ref.fast
    a, b = fast.result, ref.result
    assert np.array_equal(a.valid, b.valid)
    assert a.order.dtype == b.order.dtype == np.int32
    assert np.array_equal(np.isnan(a.phase), np.isnan(b.phase))
    assert np.nanmax(np.abs(a.phase - b.phase)) <= PHASE_TOL
    assert np.array_equal(np.isnan(a.prior), np.isnan(b.prior))
    ties = _cut_ties(a.order, b.order, a.prior, b.prior, b.phase)
    same = a.order == b.order
    assert np.nanmax(np.abs(a.prior - b.prior)[same]) <= PHASE_TOL
    scale = max(1.0, float(np.abs(ref.background).max()))
    assert np.abs(fast.background - ref.background).max() <= 1e-12 * scale
    assert np.abs(fast.modulation - ref.modulation).max() <= 1e-12 * scale
    assert np.array_equal(fast.modulation == 0, ref.modulation == 0)
    if levels:
        assert len(a.levels) == len(b.levels)
        for (fa, pa, ka), (fb, pb, kb) in zip(a.levels, b.levels):
            assert fa == fb
            assert np.array_equal(np.isnan(pa), np.isnan(pb))
            ok = ~np.isnan(kb)
            differ = ok & (ka != kb)               # +-pi cut ties of this level, as above
            assert np.all(np.abs(ka[differ] - kb[differ]) == 1)
            assert np.all(np.abs(np.abs(pa[differ] - pb[differ]) - 1.0) <= PHASE_TOL)
            assert np.abs(pa - pb)[ok & ~differ].max() <= PHASE_TOL
    assert ties <= 1e-3 * a.order.size
    return ties


def test_own_atan2_within_2_ulp_of_numpy_including_signed_zeros():
    from unwrap._fused_kernel import atan2_array
    rng = np.random.default_rng(3)
    ang = rng.uniform(-math.pi, math.pi, 1_000_000)
    rad = rng.uniform(0.0, 500.0, ang.size)
    y, x = rad * np.sin(ang), rad * np.cos(ang)
    special = np.array([0.0, -0.0, 1.0, -1.0, 1e-300, -3.0])
    yy, xx = np.meshgrid(special, special)
    y[:36], x[:36] = yy.ravel(), xx.ravel()
    t = np.linspace(0.0, 1.0, 100_001)            # every octant boundary, both reductions
    y = np.concatenate([y, t, -t, t, 1.0 + 0 * t])
    x = np.concatenate([x, 1.0 + 0 * t, -1.0 + 0 * t, -t, t])
    ours = np.empty_like(y)
    atan2_array(y, x, ours)
    ref = np.arctan2(y, x)
    assert np.abs(ours - ref).max() <= 4.5e-16
    assert np.array_equal(np.signbit(ours), np.signbit(ref))


@pytest.mark.parametrize("N", [3, 4, 5, 6, 8, 12, 16])
def test_factored_weights_differ_from_pinv_by_its_own_rounding_only(N):
    P = least_squares_weights(equal_shifts(N))
    W, Q = factor_weights(P)
    assert set(np.unique(Q).tolist()) <= {-1, 0, 1}
    assert np.abs(P - W @ Q).max() <= 3e-16
    assert Q.shape[0] < 3 * N                     # frames were merged into shared sums
    if N == 12:
        assert Q.shape[0] == 7


def test_unequal_shifts_are_not_merged():
    P = least_squares_weights([0.0, 1.0, 2.5, 4.0])
    W, Q = factor_weights(P)
    assert np.abs(P - W @ Q).max() == 0.0


@pytest.mark.parametrize("min_modulation", [0.0, 5.1])
def test_fused_equals_reference_on_noisy_8bit_stacks_with_dark_flat_and_saturated_pixels(min_modulation):
    stacks = _stacks((1, 8, 48), (12, 12, 12))
    kw = dict(width=W_P, min_modulation=min_modulation)
    fast = mf_unwrap_stacks(stacks, (1, 8, 48), fast=True, **kw)
    ref = mf_unwrap_stacks(stacks, (1, 8, 48), fast=False, **kw)
    _assert_same(fast, ref)
    v = ref.result.valid
    assert v[20:].mean() > 0.99                    # the ordinary rows unwrap
    assert not v[8:10].any() and not v[12:14].any()  # flat: undefined phase
    assert not v[10:12].all()                      # saturated crests are masked
    if min_modulation:
        assert not v[4:8].all() and v[4:8].any()


def test_fused_equals_reference_with_valid_range_saturation_off_and_levels():
    stacks = _stacks((1, 8, 48), (12, 12, 12), seed=1)
    kw = dict(width=W_P, min_modulation=2.0, saturation=None, valid_range=(1, 250), levels=True)
    fast = mf_unwrap_stacks(stacks, (1, 8, 48), fast=True, **kw)
    ref = mf_unwrap_stacks(stacks, (1, 8, 48), fast=False, **kw)
    _assert_same(fast, ref, levels=True)
    assert not ref.result.valid[14:16].all()       # frames clipped at 0 are out of range


def test_fused_equals_reference_on_16bit_stacks_mixed_step_counts_and_four_levels():
    freqs = (1, 4, 16, 64)
    stacks = _stacks(freqs, (4, 3, 6, 12), dtype=np.uint16, scale=200.0, sigma=1.0, seed=2)
    kw = dict(width=W_P, min_modulation=1000.0)
    _assert_same(mf_unwrap_stacks(stacks, freqs, fast=True, **kw),
                 mf_unwrap_stacks(stacks, freqs, fast=False, **kw))


def test_fused_equals_reference_with_unequal_shifts():
    shifts = np.array([0.0, 1.1, 2.3, 3.9, 5.0])
    stacks = _stacks((1, 8, 48), (5, 5, 5), seed=3, shifts=shifts)
    kw = dict(width=W_P, shifts=[shifts] * 3, min_modulation=5.1)
    fast = mf_unwrap_stacks(stacks, (1, 8, 48), fast=True, **kw)
    ref = mf_unwrap_stacks(stacks, (1, 8, 48), fast=False, **kw)
    _assert_same(fast, ref)
    assert ref.result.valid[20:].mean() > 0.99


def test_fused_mf_exact_k_on_noise_free_16bit_stack_up_to_128_periods():
    freqs = (1, 8, 32, 128)
    stacks = _stacks(freqs, (12, 12, 12, 12), dtype=np.uint16, scale=250.0, sigma=0.0)
    r = mf_unwrap_stacks(stacks, freqs, width=W_P, fast=True).result
    u, _, B, _ = _scene()
    good = r.valid & (B > 30)
    assert good[20:].all()
    Phi = absolute_phase(u, 128, W_P)
    k_true = np.floor((Phi + math.pi) / (2 * math.pi))     # phi in (-pi, pi]
    assert np.array_equal(r.order[good], k_true[good].astype(np.int32))
    assert np.abs(r.phase[good] - Phi[good]).max() < 2e-3


def test_out_buffers_are_reused_and_give_the_same_result():
    stacks = _stacks((1, 8, 48), (12, 12, 12), seed=4)
    first = mf_unwrap_stacks(stacks, (1, 8, 48), width=W_P)
    again = mf_unwrap_stacks(stacks, (1, 8, 48), width=W_P)
    phase_buffer = first.result.phase
    reused = mf_unwrap_stacks(stacks, (1, 8, 48), width=W_P, out=first)
    assert reused.result.phase.base is phase_buffer or reused.result.phase is phase_buffer \
        or np.shares_memory(reused.result.phase, phase_buffer)
    assert np.array_equal(reused.result.order, again.result.order)
    assert np.array_equal(reused.result.phase, again.result.phase, equal_nan=True)
    with pytest.raises(UnwrapError, match="out"):
        mf_unwrap_stacks([s[:, :10] for s in stacks], (1, 8, 48), width=W_P, out=first)


def test_float_stacks_take_the_reference_path_and_fast_true_says_why():
    stacks = [s.astype(np.float64) for s in _stacks((1, 8, 48), (12, 12, 12))]
    r = mf_unwrap_stacks(stacks, (1, 8, 48), width=W_P)
    assert not r.fast
    with pytest.raises(UnwrapError, match="uint8 or uint16"):
        mf_unwrap_stacks(stacks, (1, 8, 48), width=W_P, fast=True)


@pytest.mark.parametrize("bad, match", [
    (dict(frequencies=(1, 8)), "3 phase-shift stacks but 2 frequencies"),
    (dict(frequencies=(2, 8, 48)), "lowest frequency <= 1"),
    (dict(frequencies=(1, 48, 8)), "increase strictly"),
    (dict(shifts=[None, None, equal_shifts(5)]), "12 frames but 5 phase shifts"),
])
def test_bad_input_is_refused_with_the_reference_messages(bad, match):
    stacks = _stacks((1, 8, 48), (12, 12, 12))
    kw = dict(frequencies=(1, 8, 48), width=W_P)
    kw.update(bad)
    with pytest.raises(UnwrapError, match=match):
        mf_unwrap_stacks(stacks, **kw)


def test_two_frame_stack_is_refused():
    stacks = _stacks((1, 8, 48), (12, 12, 12))
    stacks[1] = stacks[1][:2]
    with pytest.raises(UnwrapError, match="N >= 3"):
        mf_unwrap_stacks(stacks, (1, 8, 48), width=W_P, fast=True)


@pytest.mark.realdata
def test_real_slstudio_capture_fused_equals_reference_and_is_what_the_pipeline_uses():
    from unwrap.capture import load_capture, read_stack
    from unwrap.pipeline import unwrap_orientation
    oc = load_capture(shared_data("slstudio-ps2x3-calib") / "skull_2x3").orientations["v"]
    sets = sorted(oc.sets, key=lambda s: s.frequency)
    stacks = [read_stack(s.files) for s in sets]
    kw = dict(shifts=[s.shifts for s in sets], width=oc.width, min_modulation=0.02 * 255)
    freqs = [s.frequency for s in sets]
    fast = mf_unwrap_stacks(stacks, freqs, fast=True, **kw)
    ref = mf_unwrap_stacks(stacks, freqs, fast=False, **kw)
    _assert_same(fast, ref)
    assert ref.result.valid.sum() > 80_000       # the skull
    piped = unwrap_orientation(oc, "mf").result
    assert np.array_equal(piped.order, fast.result.order)
    assert np.array_equal(piped.phase, fast.result.phase, equal_nan=True)


def test_docstring_example_runs():
    import doctest

    import unwrap.fused_mf
    result = doctest.testmod(unwrap.fused_mf)
    assert result.attempted > 0 and result.failed == 0
