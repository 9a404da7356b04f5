"""Hard cases: grazing angles, objects behind the camera or outside both views, empty scenes, a
projector pixel exactly on a pattern edge, shadows, and invalid scene files."""
import numpy as np
import pytest
import torch

from synth import (Plane, Scene, Sphere, SynthError, compute_geometry, gray_sequence, load_scene,
                   phase_sequence, render)
from synth.effects.spec import Effects
from synth.scenes.poses import rotation_xyz_deg
from synth.renderer.projection import sample_nearest

from synth_helpers import small_system


def test_empty_scene_renders_black_with_empty_truth():
    res = render(Scene(small_system(4), [], phase_sequence(("v",), (8,), 4)))
    assert int(res.images.max()) == 0 and not bool(res.geometry.hit.any())
    assert any("no camera pixel is lit" in line for line in res.plan)
    phase, order, valid = res.truth((912, 1140), phase_sequence(("v",), (8,), 4))["v"][8.0]
    assert not valid.any() and np.all(order == -1) and np.all(np.isnan(phase))


def test_object_behind_the_camera_or_outside_both_views_is_not_seen():
    system = small_system(4)
    C = system.camera.center_world
    behind = Sphere("behind", np.eye(3), C + 300 * system.camera.R[2] * -1, radius_mm=50)
    aside = Sphere("aside", np.eye(3), [5000.0, 0, 0], radius_mm=50)
    res = render(Scene(system, [behind, aside], phase_sequence(("v",), (8,), 4)))
    assert not bool(res.geometry.hit.any()) and int(res.images.max()) == 0


def test_grazing_plane_stays_finite_and_valid():
    system = small_system(4)
    # plane containing the camera's viewing direction within 0.5 deg: hits at grazing incidence
    cam_axis = system.camera.R[2]
    n = np.cross(cam_axis, [1.0, 0, 0])
    n /= np.linalg.norm(n)
    tilt = rotation_xyz_deg([0.5, 0, 0])
    n = tilt @ n
    z = n
    x = np.cross([0, 1.0, 0], z)
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(z, x), z])
    res = render(Scene(system, [Plane("grazing", R, [0, 0, 0])], phase_sequence(("v",), (8,), 4)), quantised=False)
    g = res.geometry
    assert bool(g.hit.any())
    for a in (g.depth[g.hit], g.u_p[g.lit], g.radiance_scale):
        assert bool(torch.isfinite(a).all())
    assert bool(torch.isfinite(res.images).all())


def test_projector_pixel_exactly_on_a_pattern_edge_takes_the_right_hand_pixel():
    imgs = torch.tensor([[[0.0, 1.0, 0.0]]], dtype=torch.float64)  # (1, 1, 3)
    u = torch.tensor([0.5, 1.5, 0.49999999, 1.0], dtype=torch.float64)
    v = torch.zeros(4, dtype=torch.float64)
    assert sample_nearest(imgs, u, v).tolist() == [[1.0, 0.0, 0.0, 1.0]]


def test_gray_code_rendered_matches_the_projector_column_of_every_lit_pixel():
    system = small_system(4)
    seq = gray_sequence("v", system.projector.size)
    res = render(Scene(system, [Plane("p", np.eye(3), [0, 0, 0])], seq, Effects(shading="none", falloff=False)),
                 quantised=False)
    lit = res.geometry.lit
    bits = (res.images.reshape(len(seq), -1)[:, lit] > 0.4).long()
    gray = torch.zeros(int(lit.sum()), dtype=torch.long)
    for b in bits:
        gray = gray * 2 + b
    col = gray.clone()
    shift = gray >> 1
    while bool(shift.any()):
        col ^= shift
        shift >>= 1
    assert torch.equal(col, torch.floor(res.geometry.u_p[lit] + 0.5).long())


def test_ball_in_front_of_a_wall_casts_the_predicted_shadow():
    system = small_system(4)
    wall = Plane("wall", np.eye(3), [0, 0, -150.0])
    ball = Sphere("ball", np.eye(3), [0, 0, 0], radius_mm=30)
    g = compute_geometry(Scene(system, [wall, ball], phase_sequence(("v",), (1,), 3)))
    # independent check: a wall point is shadowed iff its segment to the projector meets the ball
    on_wall = (g.object_id == 0) & g.in_field & g.facing
    Pw = (g.points_cam[on_wall].numpy() - system.camera.t) @ system.camera.R
    C = system.projector.center_world
    d = C - Pw
    L = np.linalg.norm(d, axis=1)
    d /= L[:, None]
    t_closest = np.clip(-(Pw * d).sum(1), 0, L)
    miss = np.linalg.norm(Pw + t_closest[:, None] * d, axis=1)
    expected = miss < 30.0
    assert expected.sum() > 50
    assert np.array_equal(g.shadow[on_wall].numpy(), expected)
    single = render(Scene(system, [ball], phase_sequence(("v",), (1,), 3)))
    assert any(line.startswith("cast shadows: skipped") for line in single.plan)


@pytest.mark.parametrize("text, key", [
    ('[patterns]\nsequence = [{kind = "phase", frequencies = [8], steps = 2}]', "patterns.steps"),
    ('[[objects]]\nkind = "sphere"\nradius_mm = -1\n[patterns]\nsequence = [{kind = "white"}]', "objects[0].radius_mm"),
    ('[[objects]]\nkind = "cube"\n[patterns]\nsequence = [{kind = "white"}]', "objects[0].kind"),
    ('[[objects]]\nkind = "plane"\npose = {R = [[1, 0, 0], [0, 1, 0], [0, 0, 2]]}\n[patterns]\nsequence = [{kind = "white"}]', "objects[0].pose.R"),
    ('[effects]\nbits = 9\n[patterns]\nsequence = [{kind = "white"}]', "effects.bits"),
    ('[effects]\nnoise = {full_well = 3}\n[patterns]\nsequence = [{kind = "white"}]', "effects.noise"),
    ('[[objects]]\nkind = "mesh"\nfile = "missing.obj"\n[patterns]\nsequence = [{kind = "white"}]', "missing.obj"),
    ('[objects\n', "not valid TOML"),
    ('[[objects]]\nkind = "plane"\n', "patterns.sequence"),
    ('[[objects]]\nkind = "board"\nboard = {rows = 9, cols = 11, large_markers = [[20, 1]]}\n[patterns]\nsequence = [{kind = "white"}]', "large_markers"),
])
def test_invalid_scene_files_raise_an_error_naming_the_key(tmp_path, text, key):
    p = tmp_path / "scene.toml"
    p.write_text(text)
    with pytest.raises(SynthError, match=key.replace("[", r"\[").replace("]", r"\]")):
        load_scene(p)


def test_effects_are_applied_only_when_asked_and_say_so():
    system = small_system(4)
    seq = phase_sequence(("v",), (8,), 4)
    plain = render(Scene(system, [Plane("p", np.eye(3), [0, 0, 0])], seq))
    text = "\n".join(plain.plan)
    for stage in ("cast shadows: skipped", "projector defocus: skipped", "camera defocus: skipped",
                  "sensor noise: skipped", "vignetting: skipped", "projector gamma: skipped"):
        assert stage in text
    from synth.effects.spec import Defocus, Noise
    eff = Effects(noise=Noise(seed=3), projector_defocus=Defocus(5.0, 600.0), camera_defocus=Defocus(5.0, 600.0),
                  vignetting=0.5, projector_gamma=2.2, ambient=0.05)
    full = render(Scene(system, [Plane("p", np.eye(3), [0, 0, 0])], seq, eff))
    assert {"noise", "camera defocus"} <= set(full.timings)
    again = render(Scene(system, [Plane("p", np.eye(3), [0, 0, 0])], seq, eff))
    assert torch.equal(full.images, again.images)  # seeded
    # what the plan says is what the images show: each effect alone changes them, none asked leaves
    # them as the plain render's
    assert torch.equal(render(Scene(system, [Plane("p", np.eye(3), [0, 0, 0])], seq, Effects())).images, plain.images)
    small = small_system(8)
    plain = render(Scene(small, [Plane("p", np.eye(3), [0, 0, 0])], seq))
    for name, one in (("noise", Effects(noise=Noise(seed=3))), ("projector defocus", Effects(projector_defocus=Defocus(5.0, 600.0))),
                      ("camera defocus", Effects(camera_defocus=Defocus(5.0, 600.0))), ("vignetting", Effects(vignetting=0.5)),
                      ("projector gamma", Effects(projector_gamma=2.2)), ("ambient", Effects(ambient=0.05))):
        alone = render(Scene(small, [Plane("p", np.eye(3), [0, 0, 0])], seq, one))
        assert not torch.equal(alone.images, plain.images), name
        assert not any(line.startswith(f"{name}: skipped") for line in alone.plan), (name, alone.plan)
