"""Analytic checks: a plane and a sphere rendered noise-free give closed-form depth and projector
coordinates (5e-12 relative; measured 1.4e-13 on the sphere's depth here, 1.8e-12 on an earlier build) and a decoded phase equal to the
true phase (1e-7 rad RMS; measured 1.8e-8 - 2.1e-8, the float32 images' rounding; docs/synth.md)."""
import numpy as np
import pytest
import torch

from calib import default_system
from synth import Plane, Scene, Sphere, compute_geometry, phase_sequence, render
from synth.effects.spec import Effects

from synth_helpers import nstep_phase, small_system, wrap


def closed_form(system, hit_fn):
    """Independent reference: numpy rays from DeviceModel.unproject, hit_fn -> (depth, u_p, v_p)."""
    cam, prj = system.camera, system.projector
    W, H = cam.size
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    q = np.stack([u.ravel(), v.ravel()], 1)
    C, d, ok = cam.rays_world(q)
    t = hit_fn(C, d)
    X = C + t[:, None] * d
    depth = cam.world_to_device(X)[:, 2]
    qp = prj.project(X)
    return depth, qp[:, 0], qp[:, 1], np.isfinite(t) & ok


def ray_plane(C, d):  # world plane z = 0
    t = -C[2] / d[:, 2]
    return np.where(t > 0, t, np.nan)


def ray_sphere(center, r):
    def f(C, d):
        oc = C - center
        b = d @ oc
        c = oc @ oc - r * r
        disc = b * b - c
        t = -b - np.sqrt(np.where(disc >= 0, disc, np.nan))
        return np.where(t > 0, t, np.nan)
    return f


@pytest.mark.parametrize("kind", ["plane", "sphere"])
def test_depth_and_projector_coordinates_equal_closed_form_to_5e12_relative(kind):
    system = default_system()
    obj = Plane("p", np.eye(3), [0, 0, 0]) if kind == "plane" else Sphere("s", np.eye(3), [5.0, -3.0, 10.0], radius_mm=40)
    ref = ray_plane if kind == "plane" else ray_sphere(np.array([5.0, -3.0, 10.0]), 40.0)
    g = compute_geometry(Scene(system, [obj], phase_sequence(("v",), (1,), 3)))
    depth, u_p, v_p, ok = closed_form(system, ref)
    hit = g.hit.numpy()
    assert np.array_equal(hit, ok)
    assert hit.sum() > 1000
    for ours, theirs in ((g.depth, depth), (g.u_p, u_p), (g.v_p, v_p)):
        a = ours.numpy()[hit]
        rel = np.abs(a - theirs[hit]) / np.maximum(np.abs(theirs[hit]), 1.0)
        assert rel.max() < 5e-12, rel.max()          # measured <= 1.4e-13 (sphere depth; docs/synth.md)


@pytest.mark.parametrize("kind", ["plane", "sphere"])
def test_decoded_phase_equals_true_phase_to_1e7_rad_rms_away_from_edges(kind):
    system = small_system(2)
    obj = Plane("p", np.eye(3), [0, 0, 0]) if kind == "plane" else Sphere("s", np.eye(3), [0, 0, 0], radius_mm=50)
    scene = Scene(system, [obj], phase_sequence(("v", "h"), (1, 8, 48), 12))
    res = render(scene, quantised=False)
    imgs = res.images.numpy()
    truth = res.truth(system.projector.size, scene.patterns)
    # away from edges: lit pixels whose 3x3 neighbourhood is lit, at grazing cos > 0.2 on the sphere
    lit = res.geometry.lit.reshape(imgs.shape[1:]).numpy()
    inner = lit.copy()
    inner[1:-1, 1:-1] &= lit[:-2, 1:-1] & lit[2:, 1:-1] & lit[1:-1, :-2] & lit[1:-1, 2:]
    inner[[0, -1], :] = False
    inner[:, [0, -1]] = False
    for o in ("v", "h"):
        for f in (1, 8, 48):
            names = [i for i, n in enumerate(res.names) if n.startswith(f"{o}_f{f:03d}_")]
            phi = nstep_phase(imgs[names])
            Phi, order, valid = truth[o][f]
            err = wrap(phi - Phi)[inner]
            rms = float(np.sqrt(np.mean(err ** 2)))
            assert rms < 1e-7, (o, f, rms)             # measured 1.8e-8 - 2.1e-8
            # the fringe order of the truth reproduces the absolute phase from the decoded one
            assert np.all(np.abs(phi[inner] + 2 * np.pi * order[inner] - Phi[inner]) < 5e-7)   # measured <= 9.2e-8


def test_geometry_is_computed_once_and_reused_for_another_stack():
    system = small_system(4)
    scene = Scene(system, [Plane("p", np.eye(3), [0, 0, 0])], phase_sequence(("v",), (8,), 4))
    first = render(scene)
    scene2 = Scene(system, scene.objects, phase_sequence(("h",), (8,), 4))
    second = render(scene2, geometry=first.geometry)
    assert "geometry: reused" in second.plan
    assert not any(k.startswith("geometry") for k in second.timings)
    direct = render(scene2)
    assert torch.equal(second.images, direct.images)
