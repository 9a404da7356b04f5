"""The thin lens's shared indirect light (synth.effects.lens_indirect): it equals the exact
per-aperture-point interreflection within the validated tolerance on a ball before a wall, it
changes nothing without interreflection (bit for bit), and the wall points an aperture point
sees behind the ball, hidden from the lens centre, are computed exactly (not filled from the
ball's light)."""
from dataclasses import replace

import numpy as np
import pytest
import torch

from experiments.defocus_bias import EXPOSURE, _setup, defocus_scene
from experiments.gi_bias import bias_map, compare
from synth import Scene, render
from synth.effects.spec import Defocus, Effects, Interreflection, effects_from_table
from synth.errors import SynthError
from synth.scenes.objects import Sphere


def _small(system, w=80, h=60):
    cam = system.camera
    s = w / cam.size[0]
    K = np.array(cam.K, dtype=np.float64)
    K[:2, :2] *= s
    K[:2, 2] = (K[:2, 2] + 0.5) * s - 0.5
    return replace(system, camera=cam.with_(K=K, size=(w, h)))


def _scene(ir, points=4, objects=None, **eff):
    system, d_ref, patterns = _setup(8)
    sc = defocus_scene("ball-wall-dof")
    e = Effects(exposure=EXPOSURE, fringe_sampling="analytic", reference_distance_mm=d_ref,
                camera_defocus=Defocus(80.0, 822.2, 6, points), interreflection=ir, **eff)
    return Scene(_small(system), sc.objects if objects is None else objects, patterns, e)


def test_the_option_is_validated():
    assert Interreflection().thin_lens == "shared"
    assert effects_from_table({"interreflection": {"thin_lens": "exact"}}).interreflection.thin_lens == "exact"
    with pytest.raises(SynthError, match="thin_lens"):
        effects_from_table({"interreflection": {"thin_lens": "approximate"}})


def test_shared_equals_exact_within_tolerance():
    direct = render(_scene(None), quantised=False)
    exact = render(_scene(Interreflection(thin_lens="exact")), quantised=False)
    shared = render(_scene(Interreflection(thin_lens="shared")), quantised=False)
    assert any(line.startswith("interreflection: shared") for line in shared.plan)
    assert not any(line.startswith("interreflection: shared") for line in exact.plan)
    D, E, S = (r.images.numpy().astype(np.float64) for r in (direct, exact, shared))
    hit = shared.geometry.hit.numpy().reshape(D.shape[1:])
    ind = (E - D)[:, hit]
    assert np.sqrt(np.mean(ind ** 2)) > 1e-3  # the indirect light is there to compare
    rel = np.sqrt(np.mean(((S - E)[:, hit]) ** 2)) / np.sqrt(np.mean(ind ** 2))
    assert rel < 0.1, rel
    lit = shared.geometry.lit.numpy().reshape(D.shape[1:])
    c = compare(bias_map(E, D), bias_map(S, D), lit)
    assert c["bias_rms"] > 1e-3 and c["correlation"] > 0.99 and c["diff_over_bias"] < 0.1, c


def test_without_interreflection_bitwise_unchanged():
    # interreflection off, and on but unable to change the image (a single convex ball)
    ball = [defocus_scene("ball-wall-dof").objects[0]]
    assert isinstance(ball[0], Sphere)
    off = render(_scene(None, objects=ball), quantised=False)
    for mode in ("shared", "exact"):
        on = render(_scene(Interreflection(thin_lens=mode), objects=ball), quantised=False)
        assert torch.equal(on.images, off.images)
        assert not any(line.startswith("interreflection: shared") for line in on.plan)


def test_points_the_centre_cannot_see_are_computed_exactly():
    from synth.effects.interreflection import Transport, patch_values
    from synth.effects.lens_indirect import SharedIndirect
    from synth.effects.thin_lens import aperture_rays, without_sampling
    from synth.renderer.geometry import compute_geometry

    scene = without_sampling(_scene(Interreflection()))
    cam = scene.system.camera
    centre = compute_geometry(scene)
    shared = SharedIndirect(scene, centre)
    # an aperture point at the lens's rim: it sees wall points behind the ball's outline
    g = compute_geometry(scene, rays=aperture_rays(cam, False, (40.0, 0.0), 822.2))
    hit = torch.nonzero(g.hit).squeeze(1)
    got, R, stats = shared.rows(g, hit)
    assert stats["exact"] > 0
    # the exactly computed points: wall points whose pixel in the centre's image sees the ball
    _, w = shared.neighbours(g.points_cam[hit], g.normals_cam[hit], g.object_id[hit])
    bad = torch.nonzero(w.sum(1) < 0.5).squeeze(1)
    assert bad.numel() == stats["exact"]
    q = torch.from_numpy(cam.project_device(g.points_cam[hit][bad].numpy())).round().to(torch.int64)
    W, H = cam.size
    inside = (q[:, 0] >= 0) & (q[:, 0] < W) & (q[:, 1] >= 0) & (q[:, 1] < H)
    seen = centre.object_id[q[inside, 1] * W + q[inside, 0]]
    wall_behind_ball = torch.zeros(bad.numel(), dtype=torch.bool)
    wall_behind_ball[inside] = (g.object_id[hit][bad][inside] == 1) & (seen == 0)
    assert int(wall_behind_ball.sum()) > 0
    # they equal a transport with those points as receivers, the lens centre's patches
    Rc, tc = torch.tensor(cam.R), torch.tensor(cam.t)
    P, n = g.points_cam[hit][bad], g.normals_cam[hit][bad]
    T = Transport(scene, (P - tc) @ Rc, n @ Rc, g.albedo[hit][bad], g.object_id[hit][bad], scene.effects.interreflection)
    values, _ = patch_values(scene, T.fine, [])
    want = T.apply(values)
    assert torch.allclose(got[:, bad], want, rtol=1e-9, atol=1e-12)
    assert float(want.abs().max()) > 0.1 * float(got.abs().max())  # not a comparison of zeros
