"""Per-frame intensity fluctuation: the estimator (unwrap.frame_jitter) recovers what was put in,
refuses what a set cannot tell, predicts the phase bias exactly; the twin effect
(synth.effects.frame_jitter) is absent bit for bit unless asked for and recovered when on."""
import numpy as np
import pytest
import torch

from unwrap.frame_jitter import (FrameJitterError, correct_frames, estimate_frame_jitter, expected_bias_rms,
                                 predicted_bias)
from unwrap.phase_shift import equal_shifts, wrapped_phase

N = 8
D = equal_shifts(N)


def _set(period, seed=1, harmonics=True, o_std=2.0, g_std=0.02, noise=1.0, H=120, W=160):
    """A fringe set with known per-frame offsets (grey) and gains; a shared waveform with a 2nd and
    3rd harmonic (a projector's response curve) when ``harmonics``."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    phi = 2 * np.pi * x / period + 0.3 * np.sin(y / 40)
    A = 80 + 40 * np.cos(x / 90.0) * np.sin(y / 70.0)
    B = 0.6 * A
    o = rng.normal(0, o_std, N)
    g = 1 + rng.normal(0, g_std, N)
    t = phi[None] - D[:, None, None]
    wave = np.cos(t) + (0.08 * np.cos(2 * t + 0.4) + 0.03 * np.cos(3 * t) if harmonics else 0)
    I = o[:, None, None] + g[:, None, None] * (A + B * wave) + rng.normal(0, noise, (N, H, W))
    return I, o - o.mean(), g / g.mean(), phi


def test_offsets_and_gains_of_a_high_frequency_set_are_recovered_within_0_2_percent():
    I, o, g, _ = _set(12.0)
    j = estimate_frame_jitter(I, D, min_modulation=10)
    assert j.how == "spatial low-pass"
    # tolerance: 0.2 grey on offsets of RMS 2 grey (background 80), 0.002 on gains of 2 %
    assert np.abs(j.offsets - o).max() < 0.2
    assert np.abs(j.gains - g).max() < 0.002
    assert abs(j.harmonics[2] - 0.08 * np.exp(-0.4j)) < 0.01    # B (Re h cos 2t + Im h sin 2t)
    assert 0.5 < j.sigma / np.sqrt((o ** 2).sum() / (N - 3)) < 2.0


def test_a_unit_set_needs_the_harmonic_model_and_a_reference_phase_for_its_first_harmonic():
    I, o, g, phi = _set(240.0, seed=2, g_std=0.0)      # gains: not fitted where the phases are uneven
    with pytest.raises(FrameJitterError, match="do not cover the period evenly"):
        estimate_frame_jitter(I, D, min_modulation=10, harmonics=0)
    alone = estimate_frame_jitter(I, D, min_modulation=10)
    assert alone.first_harmonic is None and alone.how.startswith("not identified")
    j = estimate_frame_jitter(I, D, min_modulation=10, reference_phase=phi)
    assert j.how == "reference phase"
    assert np.abs(j.offsets - o).max() < 0.6 and np.all(j.gains == 1)


def test_non_identifiable_sets_are_refused_with_a_named_error():
    I, *_ = _set(12.0)
    with pytest.raises(FrameJitterError, match="N >= 4"):
        estimate_frame_jitter(I[:3], D[:3])
    with pytest.raises(FrameJitterError, match="pixels"):
        estimate_frame_jitter(I[:, :20, :20], D, min_modulation=10)
    with pytest.raises(FrameJitterError, match="shifts"):
        estimate_frame_jitter(I, D[:7])


def test_predicted_bias_is_the_phase_error_of_the_jittered_frames_and_offsets_outside_the_first_harmonic_cause_none():
    _, o, g, phi = _set(12.0, noise=0.0)
    j = estimate_frame_jitter(_set(12.0, noise=0.0)[0], D, min_modulation=10)
    A, B = 90.0, 40.0
    ph = np.linspace(-3, 3, 50)
    frames = j.offsets[:, None] + j.gains[:, None] * (A + B * np.cos(ph[None] - D[:, None]))
    err = np.angle(np.exp(1j * (wrapped_phase(frames, D, saturation=None).phase - ph)))
    assert np.abs(predicted_bias(A, B, ph, j) - err).max() < 1e-9
    # offsets orthogonal to {1, cos, sin} (what the residuals show) leave the phase unchanged
    perp = j.__class__(**{**j.__dict__, "offsets": j.offsets - np.stack([np.ones(N), np.cos(D), np.sin(D)], 1)
                          @ np.linalg.lstsq(np.stack([np.ones(N), np.cos(D), np.sin(D)], 1), j.offsets, rcond=None)[0],
                          "gains": np.ones(N)})
    assert np.abs(predicted_bias(A, B, ph, perp)).max() < 1e-12
    assert expected_bias_rms(np.full(10, B), j) > 0
    # correcting the frames removes the bias
    fixed = correct_frames(frames[:, :, None], j)[:, :, 0]
    assert np.abs(np.angle(np.exp(1j * (wrapped_phase(fixed, D, saturation=None).phase - ph)))).max() < 1e-9


# ------------------------------------------------------------------ the twin effect
def _render(eff, keep_linear=False):
    from synth import Plane, Scene, phase_sequence, render
    from tests.synth_helpers import small_system

    return render(Scene(small_system(2), [Plane("wall", np.eye(3), [0, 0, 0])], phase_sequence(("v",), (16,), N), eff),
                  keep_linear=keep_linear)


def test_twin_effect_is_bit_identical_when_off_and_recovered_when_on():
    from synth.effects.frame_jitter import background, frame_factors
    from synth.effects.spec import Effects, FrameJitter, effects_from_table

    plain = _render(Effects())
    for off in (Effects(frame_jitter=None), Effects(frame_jitter=FrameJitter(0.0, 0.0, 5))):
        assert torch.equal(_render(off).images, plain.images)
    fj = effects_from_table({"frame_jitter": {"offset": 0.03, "gain": 0.01, "seed": 5}}).frame_jitter
    assert fj == FrameJitter(0.03, 0.01, 5)
    on = _render(Effects(frame_jitter=fj), keep_linear=True)
    assert not torch.equal(on.images, plain.images)
    assert any(line == "frame jitter: run" for line in on.plan)
    j = estimate_frame_jitter(on.images.numpy().astype(np.float64), D, saturation=250)
    o, g = frame_factors(fj, N)
    ref = background(on.linear) * 255                  # the effect's background, grey
    o_grey = (o - o.mean()) * ref
    # 8-bit quantisation, 16 periods over 320 px: 0.6 % of the background on offsets of 3 %,
    # 0.5 % on gains of 1 %
    assert np.abs(j.offsets - o_grey).max() < 0.006 * ref
    assert np.abs(j.gains - g / g.mean()).max() < 0.005
    j0 = estimate_frame_jitter(plain.images.numpy().astype(np.float64), D, saturation=250)
    assert j0.sigma_rel < 0.002


def test_effect_config_is_validated_and_export_draws_it_last_and_records_it():
    from synth.effects.spec import effects_from_table
    from synth.errors import SynthError
    from synth.export.config import ExportConfigError, config_from_dict
    from synth.export.scenes import draw_scene
    from tests.synth_helpers import small_system

    for bad in ({"offset": 2.0}, {"offset": -0.01}, {"gain": -0.5}, {"gain": float("nan")}):
        with pytest.raises(SynthError, match="frame_jitter"):
            effects_from_table({"frame_jitter": bad})
    with pytest.raises(SynthError, match="frame_jitter"):
        effects_from_table({"frame_jitter": {"ofset": 0.1}})
    with pytest.raises(ExportConfigError, match="frame_jitter"):
        config_from_dict({"export": {"samples": 1}, "effects": {"frame_jitter": {"offset": [0.1, 0.0]}}})
    base = {"export": {"samples": 1}, "scene": {"procedural": ["sphere"]}}
    cfg0 = config_from_dict(base)
    cfg1 = config_from_dict({**base, "effects": {"frame_jitter": {"offset": [0.01, 0.05], "gain": [0, 0.03]}}})
    system = small_system(4)
    s0, p0 = draw_scene(cfg0, system, np.random.default_rng([0, 0]))
    s1, p1 = draw_scene(cfg1, system, np.random.default_rng([0, 0]))
    assert p0["objects"] == p1["objects"]              # the same scene: drawn after everything else
    assert s0.effects.frame_jitter is None and "frame_jitter" not in p0
    fj = s1.effects.frame_jitter
    assert 0.01 <= fj.offset <= 0.05 and 0 <= fj.gain <= 0.03
    assert len(p1["frame_jitter"]["offsets"]) == len(s1.patterns) == len(p1["frame_jitter"]["gains"])
    assert p1["effects"]["frame_jitter"]["seed"] == fj.seed


@pytest.mark.realdata
def test_pyramid_frames_fluctuate_by_percent_of_the_background():
    import cv2

    from tests.conftest import shared_data

    root = shared_data("thomriiii-pyramid-mf-1-4-16", "structured", "vertical", "f_016")
    I = np.stack([cv2.imread(str(root / f"step_{k:03d}.png"), cv2.IMREAD_GRAYSCALE) for k in range(8)])
    j = estimate_frame_jitter(I.astype(np.float64), -D, saturation=250, max_pixels=30000)
    # measured (docs/unwrap.md): sigma 5 % of the background; a pure-noise capture reads ~0
    assert j.sigma_rel > 0.02
    with pytest.raises(FrameJitterError, match="N >= 4"):
        estimate_frame_jitter(I[:3].astype(np.float64), -D[:3])


def test_calib_unwrap_diagnosis_notes_fluctuating_frames_and_stays_silent_otherwise(tmp_path):
    import cv2

    from tests.conftest import DESIGN_CAPTURE_TOML
    from unwrap.frame_jitter import capture_jitter_line
    from unwrap.patterns import absolute_phase, fringe_intensity

    y, x = np.mgrid[0:48, 0:64].astype(np.float64)
    c = 5.0 + 14.1 * x + 0.3 * y
    rng = np.random.default_rng(4)
    for name, o_std in (("steady", 0.0), ("jitter", 0.05)):
        pose = tmp_path / name / "pose_00"
        pose.mkdir(parents=True)
        (tmp_path / name / "capture.toml").write_text(DESIGN_CAPTURE_TOML)
        for f in (1, 8, 48):
            for n in range(12):
                I = fringe_intensity(absolute_phase(c, f, 912), n, 12, A=30000, B=25000)
                I += (rng.normal(0, o_std) * 30000 if f == 48 else 0) + rng.normal(0, 30, I.shape)
                for o in ("v", "h"):
                    cv2.imwrite(str(pose / f"{o}_f{f:03d}_n{n:02d}.png"), np.round(I).astype(np.uint16))
        line = capture_jitter_line(tmp_path / name, pose="pose_00")
        if name == "steady":
            assert line is None
        else:
            assert line is not None and line.startswith("frames fluctuate") and "f = 48" in line


def test_calib_unwrap_checks_the_frames_only_when_asked(tmp_path, capsys):
    """``calib unwrap --check-frames`` notes a capture whose frames fluctuate; without the flag
    the command reads no frame twice and says nothing about them."""
    import cv2

    from sltwin.cli import main
    from tests.conftest import DESIGN_CAPTURE_TOML
    from unwrap.patterns import absolute_phase, fringe_intensity

    y, x = np.mgrid[0:48, 0:64].astype(np.float64)
    c = 5.0 + 14.1 * x + 0.3 * y
    rng = np.random.default_rng(5)
    pose = tmp_path / "jitter" / "pose_00"
    pose.mkdir(parents=True)
    (tmp_path / "jitter" / "capture.toml").write_text(DESIGN_CAPTURE_TOML)
    for f in (1, 8, 48):
        for n in range(12):
            I = fringe_intensity(absolute_phase(c, f, 912), n, 12, A=30000, B=25000)
            I += (rng.normal(0, 0.05) * 30000 if f == 48 else 0) + rng.normal(0, 30, I.shape)
            for o in ("v", "h"):
                cv2.imwrite(str(pose / f"{o}_f{f:03d}_n{n:02d}.png"), np.round(I).astype(np.uint16))
    base = ["unwrap", str(tmp_path / "jitter"), "--pose", "pose_00", "--no-previews", "-q"]
    assert main([*base, "-o", str(tmp_path / "plain")]) == 0
    assert "fluctuate" not in capsys.readouterr().out
    assert main([*base, "-o", str(tmp_path / "checked"), "--check-frames"]) == 0
    out = capsys.readouterr().out
    assert "note: frames fluctuate" in out and "f = 48" in out
    # a batch has no per-capture diagnosis: the flag is refused there (exit 2), not silently skipped
    assert main(["unwrap", str(tmp_path / "jitter"), str(tmp_path / "jitter"), "--pose", "pose_00", "--no-previews",
                 "-q", "-o", str(tmp_path / "batch"), "--check-frames"]) == 2
    assert "--check-frames" in capsys.readouterr().err and not (tmp_path / "batch").exists()


def test_thin_lens_render_applies_the_jitter_once_after_the_aperture_average():
    """The thin lens averages pinhole renders, then runs the camera stages once: the jitter must be
    applied to the average only (not also inside every aperture sample: twice in all)."""
    from dataclasses import replace

    from synth.effects.frame_jitter import apply_frame_jitter
    from synth.effects.spec import Defocus, Effects, FrameJitter

    base = Effects(camera_defocus=Defocus(8.0, 300.0, samples=3))
    plain = _render(base, keep_linear=True)
    assert any(line.startswith("camera defocus: thin lens") for line in plain.plan)
    fj = FrameJitter(0.04, 0.03, 7)
    on = _render(replace(base, frame_jitter=fj), keep_linear=True)
    want = apply_frame_jitter(plain.linear, fj)
    assert torch.allclose(on.linear, want, rtol=1e-6, atol=1e-7)
    assert [line for line in on.plan if line.startswith("frame jitter")] == ["frame jitter: run"]


def test_a_zero_centred_background_is_refused_not_read_as_steady():
    """Zero-centred frames (background 0 up to rounding, whose sign BLAS decides): a fluctuation
    relative to the background is undefined, so the set is refused by name (it read as steady:
    sigma / background with background <= 0); real intensities, background >= modulation, pass."""
    I, *_ = _set(12.0)
    A = I.mean(axis=0)
    with pytest.raises(FrameJitterError, match="background"):
        estimate_frame_jitter(I - A[None], D, min_modulation=10)
    with pytest.raises(FrameJitterError, match="background"):       # over-subtracted: A well below B
        estimate_frame_jitter(I - 0.9 * A[None], D, min_modulation=10)
    assert estimate_frame_jitter(I - 0.3 * A[None], D, min_modulation=10).background > 0   # contrast 0.86: kept


def test_the_frame_check_says_steady_fluctuating_or_not_measured(tmp_path):
    """``calib unwrap --check-frames``'s line never calls frames steady that it did not measure: a
    3-step capture reads "not measured", with the reason."""
    import cv2

    from tests.conftest import DESIGN_CAPTURE_TOML
    from unwrap.frame_jitter import frame_check
    from unwrap.patterns import absolute_phase, fringe_intensity

    y, x = np.mgrid[0:48, 0:64].astype(np.float64)
    c = 5.0 + 14.1 * x + 0.3 * y
    rng = np.random.default_rng(6)
    for name, steps, o_std in (("steady", 12, 0.0), ("jitter", 12, 0.05), ("three", 3, 0.05)):
        pose = tmp_path / name / "pose_00"
        pose.mkdir(parents=True)
        (tmp_path / name / "capture.toml").write_text(DESIGN_CAPTURE_TOML.replace("steps = [12, 12, 12]", f"steps = {steps}"))
        for f in (1, 8, 48):
            for n in range(steps):
                I = fringe_intensity(absolute_phase(c, f, 912), n, steps, A=30000, B=25000)
                I += (rng.normal(0, o_std) * 30000 if f == 48 else 0) + rng.normal(0, 30, I.shape)
                for o in ("v", "h"):
                    cv2.imwrite(str(pose / f"{o}_f{f:03d}_n{n:02d}.png"), np.round(I).astype(np.uint16))
    assert frame_check(tmp_path / "steady", pose="pose_00").startswith("frames steady: ")
    assert frame_check(tmp_path / "jitter", pose="pose_00").startswith("frames fluctuate")
    line = frame_check(tmp_path / "three", pose="pose_00")
    assert line.startswith("frames not measured") and ">= 4 steps" in line and "steady" not in line
