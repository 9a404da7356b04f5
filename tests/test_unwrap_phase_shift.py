"""N-step least-squares phase: round trips through unwrap.patterns, masks, validation, torch."""
import math

import numpy as np
import pytest

from unwrap import UnwrapError
from unwrap.patterns import fringe_intensity, fringe_pattern
from unwrap.phase_shift import equal_shifts, phase_noise_gain, wrapped_phase


def _stack(phi, shifts, A=120.0, B=80.0):
    return np.stack([A + B * np.cos(phi - d) for d in shifts])


@pytest.mark.parametrize("N", [3, 4, 5, 6, 12])
def test_round_trip_through_the_pattern_generator_recovers_phase_A_and_B(N):
    img = np.stack([fringe_pattern((912, 40), 48, n, N, "v", A=0.5, B=0.4) for n in range(N)])
    w = wrapped_phase(img)
    u = np.arange(912.0)
    phi_true = np.angle(np.exp(1j * 2 * np.pi * 48 * u / 912))
    d = np.angle(np.exp(1j * (w.phase[0] - phi_true)))
    assert np.abs(d).max() < 1e-12
    assert np.allclose(w.A, 0.5, atol=1e-12) and np.allclose(w.B, 0.4, atol=1e-12)
    assert w.phase.dtype == np.float64 and w.valid.all()


def test_a_step_sign_mistake_or_phase_offset_is_detected_by_the_round_trip():
    phi = np.linspace(-3.0, 3.0, 101)
    good = np.stack([fringe_intensity(phi, n, 4) for n in range(4)])
    assert np.abs(wrapped_phase(good).phase - phi).max() < 1e-12
    reversed_steps = np.stack([fringe_intensity(phi, (4 - n) % 4, 4) for n in range(4)])
    assert np.abs(wrapped_phase(reversed_steps).phase - phi).max() > 1.0  # gives -phi
    offset = np.stack([fringe_intensity(phi + 0.3, n, 4) for n in range(4)])
    assert np.abs(np.angle(np.exp(1j * (wrapped_phase(offset).phase - phi)))).min() > 0.29


def test_unequal_known_shifts_are_solved_by_least_squares():
    rng = np.random.default_rng(3)
    shifts = np.array([0.0, 0.9, 2.3, 3.1, 5.0])
    phi = rng.uniform(-np.pi, np.pi, 1000)
    w = wrapped_phase(_stack(phi, shifts), shifts)
    assert np.abs(np.angle(np.exp(1j * (w.phase - phi)))).max() < 1e-11
    assert np.allclose(w.B, 80.0) and np.allclose(w.A, 120.0)
    assert phase_noise_gain(equal_shifts(12)) == pytest.approx(2 / 12)
    assert phase_noise_gain(shifts) > 2 / 5


def test_step_axis_and_list_input():
    phi = np.linspace(-3, 3, 12).reshape(3, 4)
    st = _stack(phi, equal_shifts(6))
    a = wrapped_phase(np.moveaxis(st, 0, -1), axis=-1).phase
    b = wrapped_phase(list(st)).phase
    assert np.allclose(a, phi) and np.allclose(b, phi)


def test_modulation_near_zero_is_flagged_and_its_phase_is_nan():
    phi = np.zeros(4)
    B = np.array([50.0, 1.0, 1e-3, 0.0])
    st = np.stack([100 + B * np.cos(phi - d) for d in equal_shifts(4)])
    w = wrapped_phase(st, min_modulation=2.0)
    assert w.low_modulation.tolist() == [False, True, True, True]
    assert w.valid.tolist() == [True, False, False, False]
    assert np.isnan(w.phase[1:]).all() and w.phase[0] == pytest.approx(0.0)
    w0 = wrapped_phase(st)  # default: only B == 0 (undefined phase) is flagged
    assert w0.low_modulation.tolist() == [False, False, False, True]


def test_saturated_pixels_are_flagged_for_integer_input():
    phi = np.array([0.0, 1.0, 2.0])
    st = np.clip(_stack(phi, equal_shifts(4), A=200, B=80), 0, 255).astype(np.uint8)
    w = wrapped_phase(st)
    assert w.saturated.all() and not w.valid.any()
    ok = np.clip(_stack(phi, equal_shifts(4), A=120, B=80), 0, 255).round().astype(np.uint8)
    assert wrapped_phase(ok).valid.all()


def test_nan_and_inf_frames_are_masked_or_refused():
    st = _stack(np.zeros(3), equal_shifts(4))
    st[1, 0] = np.nan
    st[2, 2] = np.inf
    w = wrapped_phase(st)
    assert w.out_of_range.tolist() == [True, False, True]
    assert np.isnan(w.phase[[0, 2]]).all() and np.isfinite(w.phase[1])
    with pytest.raises(UnwrapError, match="NaN/inf at 2 pixel"):
        wrapped_phase(st, nonfinite="raise")
    w = wrapped_phase(_stack(np.zeros(2), equal_shifts(3)), valid_range=(0, 150))
    assert w.out_of_range.all()


@pytest.mark.parametrize("bad, msg", [
    (dict(stack=np.zeros((2, 5))), "needs N >= 3"),
    (dict(stack=np.zeros((4, 5)), shifts=[0, 1, 2]), "4 frames .* 3 phase shifts"),
    (dict(stack=np.zeros((4, 5)), shifts=[0, 0, np.pi, np.pi]), "three shifts distinct"),
    (dict(stack=[np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 4))]), "frame 2 has shape"),
    (dict(stack=np.array(["a", "b", "c"])), "expected numbers"),
    (dict(stack=np.zeros((4, 5)), axis=3), "axis 3 out of range"),
])
def test_wrong_stack_lengths_and_shapes_are_clear_errors(bad, msg):
    with pytest.raises(UnwrapError, match=msg):
        wrapped_phase(**bad)


def test_float32_accumulation_stays_far_below_8bit_quantisation_noise():
    rng = np.random.default_rng(0)
    st = rng.integers(0, 256, (12, 5000)).astype(np.uint8)
    a = wrapped_phase(st, saturation=None, min_modulation=5).phase
    b = wrapped_phase(st, saturation=None, min_modulation=5, accumulate="float32").phase
    ok = np.isfinite(a)
    assert np.abs(np.angle(np.exp(1j * (a[ok] - b[ok])))).max() < 1e-5


def test_torch_tensors_give_the_same_phase_and_exact_gradients():
    torch = pytest.importorskip("torch")
    phi = torch.linspace(-3.0, 3.0, 50, dtype=torch.float64, requires_grad=True)
    st = torch.stack([fringe_intensity(phi, n, 6, A=0.5, B=0.3) for n in range(6)])
    w = wrapped_phase(st)
    assert torch.allclose(w.phase, phi.detach(), atol=1e-12)
    w.phase.sum().backward()
    assert torch.allclose(phi.grad, torch.ones_like(phi), atol=1e-9)
    zero = torch.zeros((4, 3), dtype=torch.float64, requires_grad=True)
    w0 = wrapped_phase(zero + 0.5)
    assert not bool(w0.valid.any())
    torch.nan_to_num(w0.phase).sum().backward()
    assert torch.isfinite(zero.grad).all()  # masked pixels never poison gradients
    u8 = torch.tensor(np.round(_stack(np.array([0.5]), equal_shifts(4))).astype(np.uint8))
    assert abs(float(wrapped_phase(u8).phase[0]) - 0.5) < 0.02
