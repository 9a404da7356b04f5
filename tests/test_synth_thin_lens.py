"""Camera defocus as a thin lens (synth.effects.thin_lens, ``camera_defocus.samples``): absent unless
asked for (a board at focus renders bit-identically), one aperture point is the pinhole, a
vanishing aperture tends to it, an out-of-focus plane's fringe contrast is the aperture
points' exact transfer function, an in-focus dark plate does not darken the blurred wall
beside it (the old blur of the finished image does), and the unit-phase bias of a ball before a
wall against Blender Cycles' depth of field (a stored reference written by
``python -m bench.defocus_bias --write-reference``, tests/data)."""
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from experiments.blender_parity import parity_system
from synth import Scene, phase_sequence, render
from synth.effects.spec import Defocus, Effects, effects_from_table
from synth.effects.thin_lens import aperture_points
from synth.errors import SynthError
from synth.scenes.objects import Plane
from synth.scenes.sequence import PatternSpec, gray_sequence

DATA = Path(__file__).resolve().parent / "data"


def _facing_plane(system, depth_mm, name="board", albedo=0.8, size=None, lateral=(0.0, 0.0)):
    """A plane facing the camera (normal along its optical axis) at camera depth ``depth_mm``,
    centred ``lateral`` (x, y mm, camera frame) off the axis."""
    cam = system.camera
    R = np.asarray(cam.R)
    t = np.asarray(cam.center_world) + R.T @ np.array([lateral[0], lateral[1], depth_mm])
    return Plane(name, R.T, t, albedo, size)


def _linear(system, objects, patterns, **eff):
    e = Effects(fringe_sampling="analytic", **eff)
    return render(Scene(system, objects, patterns, e), quantised=False)


def test_the_config_is_validated_and_named():
    d = effects_from_table({"camera_defocus": {"aperture_mm": 4.0, "focus_mm": 800.0, "samples": 16}}).camera_defocus
    assert (d.samples, d.levels) == (16, 6)
    assert effects_from_table({"camera_defocus": {"aperture_mm": 4, "focus_mm": 800}}).camera_defocus.samples == 0
    for bad, key in (({"samples": -1}, "samples"), ({"samples": 2.5}, "samples"), ({"samples": True}, "samples"),
                     ({"samples": 2000}, "samples")):
        with pytest.raises(SynthError, match=key):
            effects_from_table({"camera_defocus": {"aperture_mm": 4.0, "focus_mm": 800.0, **bad}})
    assert effects_from_table({"projector_defocus": {"aperture_mm": 4.0, "focus_mm": 800.0, "samples": 8}}
                              ).projector_defocus.samples == 8


def test_aperture_points_are_equal_area_and_centred():
    p = aperture_points(64)  # even: 32 equal-area spiral points and their mirror images
    r = np.hypot(p[:, 0], p[:, 1])
    assert r.max() < 1 and np.allclose(np.sort(r ** 2), np.repeat((np.arange(32) + 0.5) / 32, 2))
    assert np.abs(p.mean(0)).max() < 1e-15 and np.allclose(p[32:], -p[:32])
    q = aperture_points(33)  # odd: the plain spiral
    assert np.allclose(np.sort(np.hypot(q[:, 0], q[:, 1]) ** 2), (np.arange(33) + 0.5) / 33)
    assert np.array_equal(aperture_points(1), np.zeros((1, 2)))


def test_a_board_at_focus_renders_bit_identically_whether_or_not_defocus_is_asked_for():
    system = parity_system(4)
    pats = phase_sequence(("v",), (1, 8), 4) + gray_sequence("v", system.projector.size, 3) + [PatternSpec("white", "white")]
    board = [_facing_plane(system, 850.0)]
    plain = render(Scene(system, board, pats, Effects()))
    asked = render(Scene(system, board, pats, Effects(camera_defocus=Defocus(40.0, 850.0, 6, 16))))
    assert "camera defocus: skipped (every pixel in focus)" in asked.plan
    assert torch.equal(plain.images, asked.images)


def test_one_aperture_point_is_the_pinhole_and_a_vanishing_aperture_tends_to_it():
    from experiments.defocus_bias import defocus_scene

    system = parity_system(4)
    objs = defocus_scene().objects
    pats = phase_sequence(("v",), (1,), 4)
    pin = _linear(system, objs, pats).images
    one = _linear(system, objs, pats, camera_defocus=Defocus(80.0, 822.2, 6, 1))
    assert any(line.startswith("camera defocus: thin lens, 1 aperture") for line in one.plan)
    assert torch.allclose(one.images, pin, atol=1e-7)
    tiny = _linear(system, objs, pats, camera_defocus=Defocus(1e-3, 822.2, 6, 8)).images
    big = _linear(system, objs, pats, camera_defocus=Defocus(80.0, 822.2, 6, 8)).images
    # away from the outline (where a 1e-5 px shift can flip which surface a pixel centre hits)
    d_tiny, d_big = (tiny - pin).abs(), (big - pin).abs()
    assert float(d_tiny.median()) < 1e-6 and float(d_big.max()) > 0.05
    assert float((d_tiny > 1e-4).float().mean()) < 0.005


def test_fringe_contrast_on_an_out_of_focus_plane_is_the_aperture_points_transfer_function():
    """A plane facing the camera at depth z, focus F: aperture point a sees the pinhole image
    shifted by ``f a (1/z - 1/F)`` px, so a fringe of local frequency nu (cycles/px, 2-vector)
    keeps ``|mean_i exp(2 pi i nu . s_i)|`` of its modulation; measured on the N-step
    modulation, interior pixels."""
    from unwrap.phase_shift import wrapped_phase

    system = parity_system(4)
    z, F, A, S, freq = 900.0, 800.0, 60.0, 12, 48
    plane = [_facing_plane(system, z)]
    pats = phase_sequence(("v",), (freq,), 8)
    pin = _linear(system, plane, pats)
    dof = _linear(system, plane, pats, camera_defocus=Defocus(A, F, 6, S))
    W, H = system.camera.size
    f_px = system.camera.fx
    u = pin.geometry.u_p.reshape(H, W).numpy()
    gy, gx = np.gradient(u * freq / system.projector.width)  # cycles per camera px
    shifts = aperture_points(S) * (A / 2) * f_px * (1 / z - 1 / F)  # (S, 2) px
    T = np.abs(np.exp(2j * np.pi * (gx[..., None] * shifts[:, 0] + gy[..., None] * shifts[:, 1])).mean(-1))
    B0 = np.asarray(wrapped_phase(pin.images.numpy().astype(np.float64), saturation=None, fill_invalid=False).B)
    B1 = np.asarray(wrapped_phase(dof.images.numpy().astype(np.float64), saturation=None, fill_invalid=False).B)
    inner = np.zeros((H, W), bool)
    inner[15:-15, 15:-15] = True
    assert 0.2 < float(np.median(T[inner])) < 0.9  # a real attenuation
    err = np.abs(B1 / B0 - T)[inner]
    assert float(np.median(err)) < 3e-3 and float(err.max()) < 2e-2


def test_an_in_focus_dark_plate_does_not_darken_the_blurred_wall_beside_it():
    """A black plate in the focus plane before a lit wall (shadows off, white light): the lens
    rays of a wall pixel beside the plate converge on the focus plane off the plate, so none
    hits it: the wall keeps its (smooth) value; a blur of the finished image darkens it."""
    system = parity_system(4)
    F = 800.0
    objs = [_facing_plane(system, F, "plate", 0.0, (30.0, 200.0), (-15.0, 0.0)), _facing_plane(system, 950.0, "wall")]
    pats = [PatternSpec("white", "white")]
    kw = dict(shadows="off")
    pin = _linear(system, objs, pats, **kw)
    lens = _linear(system, objs, pats, camera_defocus=Defocus(60.0, F, 6, 64), **kw)
    blur = _linear(system, objs, pats, camera_defocus=Defocus(60.0, F, 6), **kw)
    W, H = system.camera.size
    obj = pin.geometry.object_id.reshape(H, W).numpy()
    c = 60.0 * system.camera.fx * (1 / F - 1 / 950.0)  # wall blur disc, px (~7.7)
    col = np.where((obj == 1).all(0) == False)[0]  # noqa: E712  columns the plate covers somewhere
    edge = int(col.max())  # the plate's right edge
    band = slice(edge + 1, edge + 1 + int(c / 2))
    rows = slice(30, 90)
    p, l, b = (x.images[0].numpy()[rows, band] for x in (pin, lens, blur))
    assert (obj[rows, band] == 1).all()
    assert float(np.abs(l / p - 1).max()) < 0.01
    assert float((b / p).min()) < 0.8


def test_projector_thin_lens_matches_an_independent_brute_force_aperture_integral():
    """Projector focused on the ball's front, 40 mm aperture (the wall's blur ~19 projector px):
    the unit-phase bias of our 32-point projector aperture average against
    experiments.defocus_bias.projector_reference_bias (a 12 x 24 polar midpoint grid, its own
    projection, sphere visibility and radiometry in numpy). Cycles cannot serve here: the
    twin's projector is a textured spot light, and any radius breaks its texture lookup
    (../shared/docs/BLENDER-NOTES.md: at 1 mm a white pattern renders at 5 % of its level).
    The old route (a Gaussian attenuation of the pattern) moves no phase at all."""
    from experiments.defocus_bias import PROJECTOR_FOCUS_MM, ours_dof_images, projector_reference_bias
    from experiments.gi_bias import _setup, bias_map, compare, comparison_mask

    system, _, _ = _setup(8)
    pin, r0 = ours_dof_images("ball-wall-dof", None)
    ref = projector_reference_bias(r0.geometry, system, aperture_mm=40.0, focus_mm=PROJECTOR_FOCUS_MM,
                                   radii=12, angles=24)
    m = comparison_mask(r0.geometry, pin, pin) & np.isfinite(ref)
    lens, r = ours_dof_images("ball-wall-dof", None, projector_defocus=Defocus(40.0, PROJECTOR_FOCUS_MM, 6, 32))
    assert any(line.startswith("projector defocus: thin lens, 32") for line in r.plan)
    c = compare(ref, bias_map(lens, pin), m)
    assert c["bias_rms"] > 1e-4 and c["correlation"] > 0.95 and c["diff_over_bias"] < 0.6
    old, _ = ours_dof_images("ball-wall-dof", None, projector_defocus=Defocus(40.0, PROJECTOR_FOCUS_MM, 6))
    assert float(np.abs(bias_map(old, pin)[m]).max()) < 1e-6


def test_camera_defocus_bias_of_a_ball_before_a_wall_against_cycles():
    """The stored Cycles reference (depth of field, 80 mm aperture focused on the ball's front,
    256 samples x 2 seeds, direct light; tests/data/defocus_bias_ball_wall.npz, written by
    ``python -m bench.defocus_bias --write-reference``): the unit-phase bias of our 32-point thin
    lens correlates >= 0.95 with it and the RMS difference is <= 25 % of the bias RMS (measured
    0.15), over every compared pixel and within the outline / shadow-edge band where defocus
    mixes light; the old blur of the finished image correlates less (0.63) and misses by more
    (1.06)."""
    from experiments.defocus_bias import ours_dof_bias, outline_band
    from experiments.gi_bias import compare, load_reference

    ref, mask, meta = load_reference(DATA / "defocus_bias_ball_wall.npz")
    lens = ours_dof_bias(samples=32, focus_mm=float(meta["focus_mm"]), aperture_mm=float(meta["aperture_mm"]))
    band = mask & outline_band(lens["geometry"])
    c_all, c_band = compare(ref, lens["bias"], mask), compare(ref, lens["bias"], band)
    assert c_all["bias_rms"] > 10 * float(meta["noise_rms_per_seed"])
    assert c_all["correlation"] >= 0.95 and c_band["correlation"] >= 0.95
    assert c_band["diff_over_bias"] <= 0.25 and c_all["diff_over_bias"] <= 0.25
    old = compare(ref, ours_dof_bias(samples=0, focus_mm=float(meta["focus_mm"]),
                                     aperture_mm=float(meta["aperture_mm"]))["bias"], mask)
    assert old["correlation"] < c_all["correlation"] - 0.2 and old["diff_over_bias"] > 2 * c_all["diff_over_bias"]


def test_the_sensor_runs_once_on_the_aperture_average_and_the_plan_says_so():
    """Noise, PSF tail, gain, response and quantisation act on the mean (never per point): the
    quantised output is round(clip(gain v, 0, sat)^g 255) of the kept linear mean, and the plan
    has no contradictory "skipped" line from an aperture point's render."""
    from experiments.defocus_bias import defocus_scene
    from synth.effects.spec import PsfTail

    system = parity_system(4)
    pats = phase_sequence(("v",), (1,), 4)
    eff = dict(camera_defocus=Defocus(80.0, 822.2, 6, 4), gain=1.2, saturation=0.95, camera_gamma=0.7)
    r = render(Scene(system, defocus_scene().objects, pats, Effects(**eff)), keep_linear=True)
    ref = torch.round((r.linear.double() * 1.2).clamp(0, 0.95) ** 0.7 * 255)
    assert float((r.images.double() - ref).abs().max()) <= 1
    t = render(Scene(system, defocus_scene().objects, pats, Effects(camera_psf_tail=PsfTail(0.1, 5.0), **eff)))
    assert "camera PSF tail: run" in t.plan and "camera PSF tail: skipped (not asked for)" not in t.plan
    assert not any(line.startswith("camera defocus: skipped") for line in t.plan)
    assert "camera response: skipped (gamma 1.0)" not in t.plan
    assert any(line.startswith("cast shadows: computed") for line in t.plan)  # the geometry's own lines stay


def test_a_projector_only_lens_finds_the_camera_hits_once_and_renders_as_when_it_found_them_per_point(monkeypatch):
    """Only the projector is sampled: the camera's rays and so their nearest hits are the same at
    every aperture point, computed once (for the lens centre too); the images are those of a
    per-point search (the route before), within float rounding."""
    import synth.renderer.geometry as G
    from experiments.defocus_bias import defocus_scene

    system = parity_system(4)
    W, H = system.camera.size
    pats = phase_sequence(("v",), (1, 8), 4)
    scene = Scene(system, defocus_scene().objects, pats,
                  Effects(fringe_sampling="analytic", projector_defocus=Defocus(40.0, 760.0, 6, 6)))
    calls = []
    search = G.nearest_surface

    def counting(objects, rays):
        if rays.key == "camera" and rays.dirs.shape[0] == W * H:
            calls.append(rays)
        return search(objects, rays)

    monkeypatch.setattr(G, "nearest_surface", counting)
    once = render(scene, quantised=False)
    assert any(line.startswith("projector defocus: thin lens, 6") for line in once.plan)
    assert len(calls) == 1
    # the route before: every aperture point's geometry searches the camera rays again
    plain = G.compute_geometry
    monkeypatch.setattr(G, "compute_geometry", lambda *a, hits=None, **k: plain(*a, **k))
    calls.clear()
    per_point = render(scene, quantised=False)
    assert len(calls) == 2 + 6                  # the shared search (unused now), the centre's, one per point
    assert float(once.images.std()) > 0.05
    assert torch.allclose(once.images, per_point.images, rtol=0, atol=1e-6)
