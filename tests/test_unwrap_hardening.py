"""Unwrapping without silent wrong answers (issue 15, item 2): the pattern's edge, captures in another
phase-shift convention, frames that do not belong together, and the modulation threshold from the
reliability model."""
import math

import cv2
import numpy as np
import pytest

from unwrap.consistency import prior_check
from unwrap.errors import UnwrapError
from unwrap.fused_mf import mf_unwrap_stacks
from unwrap.patterns import absolute_phase, fringe_intensity, projector_coordinate
from unwrap.phase_shift import wrapped_phase
from unwrap.reliability import fit_noise_sigma
from unwrap.pipeline import unwrap_capture
from unwrap.plan import parse_set
from unwrap.reliability import error_rate, modulation_threshold, phase_sigma
from unwrap.temporal import mf_unwrap, mw_unwrap, nt_unwrap

W = 1140


def _edge_coordinates():
    """Projector rows within 3.5 px of both ends of the pattern, which covers [-0.5, W - 0.5)."""
    return np.concatenate([np.linspace(-0.5, 3.0, 4000), np.linspace(W - 4.0, W - 0.5 - 1e-9, 4000)])[None, :]


def _stack(u, f, steps=12, A=128.0, B=100.0, dtype=np.uint8):
    return np.stack([np.round(fringe_intensity(absolute_phase(u, f, W), n, steps, A, B)) for n in range(steps)]).astype(dtype)


def _check_inside_and_exact(phase, frequency, u, valid):
    coord = projector_coordinate(phase, frequency, W)
    assert valid.all()
    assert ((coord >= -0.5) & (coord < W - 0.5)).all(), "a coordinate outside the projector"
    err = np.abs(coord - u)
    # the pattern repeats at every frequency: a pixel within the base phase's quantisation noise
    # of the end (W - 0.5) may come out as the same place at the start (-0.5): nothing else is wrong
    wrong = err > 0.05
    assert np.all(W - 0.5 - u[wrong] < 0.01), u[wrong]
    assert wrong.sum() <= 10


@pytest.mark.parametrize("fast", [True, False])
def test_pixels_at_the_last_projector_rows_never_decode_outside_the_projector(fast):
    # issue 15: at 1/8/96 periods, 8-bit, noise-free, pixels lit by the last rows got k = 0 and a
    # coordinate of -0.5 px (their base phase crossed the 2 pi cut); the range constraint moves
    # them back by one pattern period
    u = _edge_coordinates()
    freqs = (1, 8, 96)
    r = mf_unwrap_stacks([_stack(u, f) for f in freqs], freqs, width=W, fast=fast).result
    _check_inside_and_exact(r.phase, 96, u, r.valid)
    assert int(r.order.max()) == 96


def test_the_range_constraint_holds_for_mw_and_nt_too():
    u = _edge_coordinates()
    phases = {f: wrapped_phase(_stack(u, f)).phase for f in (95, 96)}
    r = mw_unwrap([phases[96], phases[95]], (96, 95), width=W)
    _check_inside_and_exact(r.phase, 96, u, r.valid)
    r = nt_unwrap([phases[95], phases[96]], (95, 96), width=W)
    _check_inside_and_exact(r.phase, 96, u, r.valid)


def test_a_decode_outside_the_pattern_that_no_period_explains_is_invalid():
    # a base of 0.75 periods: the ladder does not repeat across the pattern, so nothing to move by
    u = np.array([[-3.0, 10.0, 500.0]])
    phases = [np.angle(np.exp(1j * absolute_phase(u, f, W))) for f in (0.75, 6.0)]
    r = mf_unwrap(phases, (0.75, 6.0), width=W)
    assert r.valid.tolist() == [[False, True, True]]


# -- captures in another convention -----------------------------------------------------------

TOML = """
[pattern]
steps = {steps}
frequencies = [1, 8, 48]
{extra}
[camera]
size = [96, 64]

[projector]
size = [912, 1140]
"""


def _coords():
    y, x = np.mgrid[0:64, 0:96].astype(np.float64)
    return {"v": (3.0 + 9.0 * x + 0.4 * y, 912), "h": (5.0 + 17.1 * y + 0.3 * x, 1140)}


def _capture(folder, delta, *, extra="", steps=6):
    """A DESIGN.md capture whose frame n is A + B cos(Phi - delta(n, N))."""
    pose = folder / "pose_00"
    pose.mkdir(parents=True)
    (folder / "capture.toml").write_text(TOML.format(steps=steps, extra=extra))
    for o, (c, extent) in _coords().items():
        for f in (1, 8, 48):
            for n in range(steps):
                img = 120 + 90 * np.cos(absolute_phase(c, f, extent) - delta(n, steps))
                cv2.imwrite(str(pose / f"{o}_f{f:03d}_n{n:02d}.png"), np.round(img).astype(np.uint8))
    return folder


def _assert_exact(results):
    for o, (c, extent) in _coords().items():
        r = results[o].result
        assert r.valid.all()
        assert np.abs(projector_coordinate(r.phase, 48, extent) - c).max() < 0.05


def other_lab(n, N):   # written as A + B cos(Phi + pi + 2 pi n/N): opposite sign and a pi offset
    return -math.pi - 2 * math.pi * n / N


def test_another_labs_convention_is_refused_by_name_and_decodes_exactly_with_its_capture_toml_keys(tmp_path):
    with pytest.raises(UnwrapError, match="phase_offset") as err:
        unwrap_capture(_capture(tmp_path / "lab", other_lab))
    assert "0 %" in str(err.value) and "--no-prior-check" in str(err.value)
    keys = "shift_sign = -1\nphase_offset = 3.141592653589793"
    _assert_exact(unwrap_capture(_capture(tmp_path / "declared", other_lab, extra=keys)))


def test_explicit_shifts_in_capture_toml_decode_unequal_steps_exactly(tmp_path):
    shifts = [0.0, 1.1, 2.0, 3.3, 4.1, 5.4]
    extra = f"shifts = {shifts}"
    _assert_exact(unwrap_capture(_capture(tmp_path / "c", lambda n, N: shifts[n], extra=extra)))
    with pytest.raises(UnwrapError, match=r"shifts\[0\] must hold 6"):
        unwrap_capture(_capture(tmp_path / "bad", lambda n, N: shifts[n], extra="shifts = [0.0, 1.0]"))


def test_a_wrong_shift_sign_alone_mirrors_the_pattern_and_cannot_be_seen_in_the_phases(tmp_path):
    # documented limitation: the sign alone decodes 2 pi f - Phi, the mirror image u -> W - u,
    # which is as consistent as the truth (the priors stay on integers)
    res = unwrap_capture(_capture(tmp_path / "sign", lambda n, N: -2 * math.pi * n / N))
    for o, (c, extent) in _coords().items():
        r = res[o].result
        assert all(x == 1.0 for _, x in res[o].prior_check)
        mirrored = projector_coordinate(r.phase, 48, extent)
        assert np.abs(mirrored - (extent - c)).max() < 0.05


def test_prior_check_is_one_for_a_right_decode_and_low_for_a_wrong_ladder():
    u = np.linspace(0, 900, 3000)
    phases = [np.angle(np.exp(1j * absolute_phase(u, f, 912))) for f in (1, 8, 48)]
    assert [x for _, x in prior_check(mf_unwrap(phases, (1, 8, 48), width=912))] == [1.0, 1.0]
    wrong = [x for _, x in prior_check(mf_unwrap(phases, (1, 6, 48), width=912))]   # frames of 8 called 6
    assert min(wrong) < 0.65


# -- frames that do not belong together -----------------------------------------------------


def test_mixed_bit_depth_size_and_extra_frames_are_refused_naming_the_frame(tmp_path):
    folder = _capture(tmp_path / "c", lambda n, N: 2 * math.pi * n / N)
    pose = folder / "pose_00"
    frame = pose / "h_f008_n03.png"
    original = frame.read_bytes()
    cv2.imwrite(str(frame), cv2.imread(str(frame), -1).astype(np.uint16) * 257)
    with pytest.raises(UnwrapError, match="h_f008_n03.png: uint16 frame among uint8 frames"):
        unwrap_capture(folder)
    cv2.imwrite(str(frame), np.zeros((64, 95), np.uint8))
    with pytest.raises(UnwrapError, match="h_f008_n03.png: frame is 95x64"):
        unwrap_capture(folder)
    frame.write_bytes(original)
    cv2.imwrite(str(pose / "h_f008_n06.png"), np.zeros((64, 96), np.uint8))
    with pytest.raises(UnwrapError, match=r"h_f008_n06.png'\] are not described"):
        unwrap_capture(folder)


def test_threshold_options_are_checked(tmp_path):
    folder = _capture(tmp_path / "c", lambda n, N: 2 * math.pi * n / N)
    for bad, message in ((-1.0, "finite number >= 0"), (float("nan"), "finite number >= 0"),
                         (1e9, "exceeds the largest modulation uint8")):
        with pytest.raises(UnwrapError, match=message):
            unwrap_capture(folder, min_modulation=bad)
    with pytest.raises(UnwrapError, match="not both"):
        unwrap_capture(folder, min_modulation=5, max_error_rate=1e-3)
    with pytest.raises(UnwrapError, match="no valid pixel"):
        unwrap_capture(folder, min_modulation=100)   # B = 90 everywhere


# -- the modulation threshold from the reliability model ------------------------------------


def test_noise_from_the_fit_residuals_matches_the_noise_put_in():
    rng = np.random.default_rng(1)
    phi = rng.uniform(-np.pi, np.pi, 20000)
    for steps, shifts in ((8, None), (5, np.array([0.0, 1.0, 2.5, 3.7, 5.0]))):
        delta = 2 * np.pi * np.arange(steps) / steps if shifts is None else shifts
        stack = 100 + 40 * np.cos(phi[None, :] - delta[:, None]) + rng.normal(0, 3.0, (steps, phi.size))
        assert fit_noise_sigma(stack, shifts) == pytest.approx(3.0, rel=0.02)
    with pytest.raises(UnwrapError, match="N >= 4"):
        fit_noise_sigma(np.zeros((3, 10)))


@pytest.mark.parametrize("method, freqs", [("mf", (1, 8, 48)), ("mw", (48, 47)), ("nt", (47, 48))])
def test_modulation_threshold_gives_the_asked_error_rate(method, freqs):
    B = modulation_threshold(method, freqs, 12, 2.0, 1e-3)
    assert error_rate(method, freqs, phase_sigma(2.0, 12, B)) <= 1e-3
    assert error_rate(method, freqs, phase_sigma(2.0, 12, B / 1.02)) > 1e-3


def test_max_error_rate_keeps_pixels_whose_wrong_orders_the_model_predicts(tmp_path):
    # modulation falling from 60 to 2 grey levels across the image, noise 3 grey levels, 4 steps:
    # the default 2 % threshold (5.1) keeps pixels with many wrong orders, the model's does not
    rng = np.random.default_rng(7)
    folder = tmp_path / "c"
    pose = folder / "pose_00"
    pose.mkdir(parents=True)
    (folder / "capture.toml").write_text(TOML.format(steps=4, extra="").replace("[96, 64]", "[400, 200]"))
    y, x = np.mgrid[0:200, 0:400].astype(np.float64)
    u = 2.0 + 2.2 * x + 0.1 * y
    B = 60.0 * (2.0 / 60.0) ** (x / 399.0)
    for o in ("v", "h"):
        for f in (1, 8, 48):
            for n in range(4):
                img = 128 + B * np.cos(absolute_phase(u, f, 912 if o == "v" else 1140) - 2 * np.pi * n / 4)
                img = np.clip(np.round(img + rng.normal(0, 3.0, img.shape)), 0, 255).astype(np.uint8)
                cv2.imwrite(str(pose / f"{o}_f{f:03d}_n{n:02d}.png"), img)

    def wrong_orders(r):   # a wrong order moves the absolute phase by 2 pi (k at the +-pi cut may differ by 1)
        return int(np.sum(r.result.valid & (np.abs(r.result.phase - absolute_phase(u, 48, 912)) > np.pi)))

    default = unwrap_capture(folder, check_prior=False)["v"]
    modelled = unwrap_capture(folder, max_error_rate=1e-3)["v"]
    assert modelled.noise_sigma == pytest.approx(3.0, rel=0.1)
    assert modelled.min_modulation > default.min_modulation
    kept = int(modelled.result.valid.sum())
    assert wrong_orders(default) > 100
    assert wrong_orders(modelled) <= max(5, 3 * modelled.predicted_error_rate * kept)
    assert modelled.predicted_error_rate <= 1e-3


# -- plan-fringes accepts exactly what unwrap decodes -----------------------------------------


@pytest.mark.parametrize("text", ["mf:1,8,48", "mf:8,48", "mf:48,8,1", "mf:1,1", "mw:48,47", "mw:48,46",
                                  "mw:70,64,59", "mw:70,65,60", "nt:47,48", "nt:48,48", "nt:46,48", "nt:47.5,48"])
def test_plan_fringes_refuses_exactly_the_ladders_unwrap_refuses(text):
    method, freqs = text.split(":")
    f = [float(v) for v in freqs.split(",")]
    phases = [np.zeros((2, 2))] * len(f)
    decoder = {"mf": mf_unwrap, "mw": mw_unwrap, "nt": nt_unwrap}[method]
    try:
        decoder(phases, f)
        unwrap_ok = True
    except UnwrapError:
        unwrap_ok = False
    try:
        parse_set(text)
        plan_ok = True
    except UnwrapError:
        plan_ok = False
    assert plan_ok == unwrap_ok


def test_plan_fringes_calls_gray_code_gray_as_unwrap_does():
    assert parse_set("gray:32") == ("gray", [32.0])
    assert parse_set("cgray:32") == ("gray", [32.0])   # the old name still read
