"""The camera PSF's tail and the camera response curve (synth.effects.response): validated config,
absent unless asked for (bit-identical renders), the tail's impulse response and energy, its
exact transfer function on a fringe, and the response curve's place (after the linear light
transport: without mixing it biases the phase exactly as the projector's gamma does)."""
import math

import numpy as np
import pytest
import torch

from experiments.blender_parity import parity_system
from synth import Scene, phase_sequence, render
from synth.effects.response import psf_tail
from synth.effects.spec import Effects, PsfTail, effects_from_table
from synth.errors import SynthError
from synth.scenes.objects import Plane, Sphere
from synth.scenes.sequence import PatternSpec, gray_sequence


def _facing_plane(system, depth_mm):
    R = np.asarray(system.camera.R)
    return Plane("board", R.T, np.asarray(system.camera.center_world) + R.T @ np.array([0.0, 0.0, depth_mm]), 0.8)


def test_the_config_is_validated_and_named():
    e = effects_from_table({"camera_gamma": 0.45, "camera_psf_tail": {"fraction": 0.05, "sigma_px": 20}})
    assert e.camera_gamma == 0.45 and e.camera_psf_tail == PsfTail(0.05, 20.0)
    for bad, key in (({"camera_gamma": 0.0}, "camera_gamma"), ({"camera_gamma": "2"}, "camera_gamma"),
                     ({"camera_psf_tail": {"fraction": 2, "sigma_px": 3}}, "fraction"),
                     ({"camera_psf_tail": {"fraction": 0.1, "sigma_px": 0}}, "sigma_px"),
                     ({"camera_psf_tail": {"fraction": 0.1}}, "sigma_px"),
                     ({"camera_psf_tail": {"fraction": 0.1, "sigma_px": 3, "shape": 1}}, "shape"),
                     ({"camera_psf_tail": 0.1}, "camera_psf_tail")):
        with pytest.raises(SynthError, match=key):
            effects_from_table(bad)


def test_a_board_renders_bit_identically_whether_or_not_an_inactive_tail_or_curve_is_given():
    system = parity_system(4)
    pats = phase_sequence(("v",), (1, 8), 4) + gray_sequence("v", system.projector.size, 3) + [PatternSpec("white", "white")]
    objs = [_facing_plane(system, 850.0)]
    plain = render(Scene(system, objs, pats, Effects()))
    asked = render(Scene(system, objs, pats, Effects(camera_gamma=1.0, camera_psf_tail=PsfTail(0.0, 10.0))))
    assert "camera PSF tail: skipped (fraction 0)" in asked.plan and "camera response: skipped (gamma 1.0)" in asked.plan
    assert torch.equal(plain.images, asked.images)


def test_the_tail_of_an_impulse_is_the_gaussian_and_keeps_its_energy():
    img = torch.zeros((1, 121, 161), dtype=torch.float32)
    img[0, 60, 80] = 1.0
    a, s = 0.1, 6.0
    out = psf_tail(img, a, s)[0].double().numpy()
    assert out.sum() == pytest.approx(1.0, abs=1e-6)
    yy, xx = np.mgrid[:121, :161]
    g = a * np.exp(-((yy - 60) ** 2 + (xx - 80) ** 2) / (2 * s * s)) / (2 * math.pi * s * s)
    g[60, 80] += 1 - a
    assert np.abs(out - g).max() < 1e-7
    # light spread beyond the sensor is lost: an impulse at the border keeps ~ (1 - a) + a / 2
    img2 = torch.zeros_like(img)
    img2[0, 60, 0] = 1.0
    assert float(psf_tail(img2, a, s).sum()) == pytest.approx(1 - a + a * 0.5, abs=0.02)


def test_fringe_contrast_under_the_tail_is_its_transfer_function():
    from unwrap.phase_shift import wrapped_phase

    system = parity_system(4)
    a, s, freq = 0.2, 2.0, 48
    objs = [_facing_plane(system, 850.0)]
    pats = phase_sequence(("v",), (freq,), 8)
    e = dict(fringe_sampling="analytic", falloff=False)
    pin = render(Scene(system, objs, pats, Effects(**e)), quantised=False)
    tail = render(Scene(system, objs, pats, Effects(camera_psf_tail=PsfTail(a, s), **e)), quantised=False)
    W, H = system.camera.size
    gy, gx = np.gradient(pin.geometry.u_p.reshape(H, W).numpy() * freq / system.projector.width)
    T = (1 - a) + a * np.exp(-2 * math.pi ** 2 * s ** 2 * (gx ** 2 + gy ** 2))
    B0 = np.asarray(wrapped_phase(pin.images.numpy().astype(np.float64), saturation=None, fill_invalid=False).B)
    B1 = np.asarray(wrapped_phase(tail.images.numpy().astype(np.float64), saturation=None, fill_invalid=False).B)
    inner = (slice(12, -12), slice(12, -12))
    assert float(np.median(T[inner])) < 0.9
    assert float(np.abs(B1 / B0 - T)[inner].max()) < 2e-3


def test_without_mixing_the_camera_curve_biases_the_phase_as_the_projector_gamma_does():
    """``(s p)^g = s^g p^g``: on a pinhole render without ambient light, a camera curve g and a
    projector gamma g give the same N-step phase (4 steps: the 3rd and 5th harmonics reach it)."""
    from unwrap.phase_shift import wrapped_phase

    system = parity_system(4)
    objs = [Sphere("ball", np.eye(3), [0, 0, 0], 0.8, 25.4), _facing_plane(system, 900.0)]
    pats = phase_sequence(("v",), (1,), 4)

    def phase(**kw):
        r = render(Scene(system, objs, pats, Effects(fringe_sampling="analytic", **kw)), quantised=False)
        w = wrapped_phase(r.images.numpy().astype(np.float64), saturation=None, fill_invalid=False)
        return np.asarray(w.phase), r.geometry.lit.reshape(120, 160).numpy()

    p0, lit = phase()
    pc, _ = phase(camera_gamma=2.2)
    pp, _ = phase(projector_gamma=2.2)
    d = np.angle(np.exp(1j * (pc - p0)))[lit]
    assert np.abs(d).max() > 5e-3  # a real bias
    assert np.abs(np.angle(np.exp(1j * (pc - pp)))[lit]).max() < 2e-5
    # quantised output: round(clip(gain v, 0, sat)^g (2^b - 1))
    lin = render(Scene(system, objs, pats, Effects(gain=1.3, saturation=0.9)), quantised=False, keep_linear=True).linear
    q = render(Scene(system, objs, pats, Effects(gain=1.3, saturation=0.9, camera_gamma=0.5))).images
    ref = torch.round((lin.double() * 1.3).clamp(0, 0.9) ** 0.5 * 255)
    assert float((q.double() - ref).abs().max()) <= 1
