"""Fringe orders of the renderer agree with what unwrap computes (N-step + MF 1-8-48) on the
noise-free rendered images at every valid pixel, as the paper computes its labels."""
import numpy as np
import pytest

from synth import Plane, Scene, Sphere, phase_sequence, render
from unwrap.phase_shift import wrapped_phase
from unwrap.temporal import mf_unwrap

from synth_helpers import small_system


@pytest.fixture(scope="module")
def ball_on_wall():
    system = small_system(2)
    scene = Scene(system, [Plane("wall", np.eye(3), [0, 0, -80.0]), Sphere("ball", np.eye(3), [0, 0, 0], radius_mm=40)],
                  phase_sequence(("v", "h"), (1, 8, 48), 12))
    return system, scene, render(scene, quantised=False)


def _unwrap(res, o, extent, imgs):
    phis = [wrapped_phase(imgs[[i for i, n in enumerate(res.names) if n.startswith(f"{o}_f{f:03d}_")]]).phase
            for f in (1, 8, 48)]
    return mf_unwrap(phis, [1, 8, 48], width=extent)


@pytest.mark.parametrize("o, extent", [("v", 912), ("h", 1140)])
def test_fringe_orders_agree_with_unwrap_at_every_valid_pixel(ball_on_wall, o, extent):
    system, scene, res = ball_on_wall
    Phi, order, valid = res.truth(system.projector.size, scene.patterns)[o][48.0]
    u = _unwrap(res, o, extent, res.images.numpy())
    assert valid.sum() > 50000 and np.all(np.asarray(u.valid)[valid])
    assert np.array_equal(np.asarray(u.order)[valid], order[valid])
    assert np.abs(np.asarray(u.phase)[valid] - Phi[valid]).max() < 1e-6


def test_8bit_images_unwrap_without_fringe_order_jumps(ball_on_wall):
    system, scene, res = ball_on_wall
    from synth.effects.sensor import quantise
    imgs8 = quantise(res.images.clone(), 8).numpy()
    Phi, order, valid = res.truth(system.projector.size, scene.patterns)["v"][48.0]
    u = _unwrap(res, "v", 912, imgs8)
    ok = valid & np.asarray(u.valid)
    # orders may differ by one only where the phase sits on the wrap cut; absolute phase agrees
    assert np.abs(np.asarray(u.phase)[ok] - Phi[ok]).max() < 0.5
