"""The Cycles test set's pipeline, tiny (64x48 crop, 4 samples, one held-out mesh): Cycles renders
it, the file is one the evaluation reads, its true orders are the twin's geometry and agree with
Cycles' own (direct light, noise-free), and the phase-shift stack synthesised from three basis
frames is what Cycles renders for a step with the same seed (light transport is linear)."""
import sys

import numpy as np
import pytest

from synth.blender_twin import blender_available
from tests.conftest import shared_data

CYCLES = [pytest.mark.blender, pytest.mark.realdata,
          pytest.mark.skipif(not blender_available(sys.executable), reason="bpy not installed (make test installs it)")]


def _cycles(fn):
    for m in CYCLES:
        fn = m(fn)
    return fn

SIZE = (64, 48)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    from experiments import cycles_testset as ct

    mesh_dir = shared_data("meshes")
    assert (mesh_dir / "suzanne.obj").is_file()
    work = tmp_path_factory.mktemp("cycles_set")
    r = ct.build_testset(work / "test.h5", scenes=("suzanne-wall",), size=SIZE, samples=4, cache_dir=work,
                         unit_seeds=(0,))
    return ct, work, r


@_cycles
def test_file_reads_and_true_orders_are_the_twin_geometry(tiny):
    import h5py

    from experiments.learned_evaluation import TestSource, score
    from synth.renderer.truth import phase_truth
    from unwrap.dataset import FringeOrderDataset

    ct, work, r = tiny
    path = work / "test.h5"
    system = ct.testset_system(SIZE)
    patterns, _, _ = ct.patterns_and_basis(system)
    geom = ct.twin_geometry(ct.build_scene("suzanne-wall"), system, patterns)
    with h5py.File(path, "r") as h5:
        assert h5.attrs["complete"] and h5.attrs["kind"] == "twin"
        stored = h5["v/order"][0]
    for j, f in enumerate(ct.FREQUENCIES):
        assert np.array_equal(stored[j], phase_truth(geom, system.projector.size, "v", f)[1])
    for f in (48, 96):
        it = FringeOrderDataset(str(path), method="mf", frequencies=(1, f), orientation="v", crop=None, seed=0)[0]
        valid = it["valid"].numpy()
        assert valid.sum() > 0.5 * SIZE[0] * SIZE[1]
        # order_true (from the stored coordinate, relative to the measured phase) differs from the
        # geometric order only by a wrap at the +-pi cut
        d = (it["order_true"].numpy() - stored[ct.FREQUENCIES.index(f)])[valid]
        assert np.isin(d, (-1, 0, 1)).all() and np.mean(d == 0) > 0.95
        s = score(TestSource(files=[str(path)], orientations=("v",)), "mf", f, {}, filtered_window=15)
        assert s.counts["Traditional"].counted == int(valid.sum())
        assert 0.0 <= s.counts["Traditional"].rate < 0.5


@_cycles
def test_cycles_geometry_agrees_with_the_twin(tiny):
    """Cycles' direct light (1 sample, pixel centres) is lit where the twin is, and traditional MF
    on its noise-free frames gives the twin's orders wherever both are lit."""
    from synth.export.sample import edge_mask
    from synth.renderer.truth import phase_truth
    from unwrap.temporal import mf_unwrap

    ct, work, r = tiny
    system = ct.testset_system(SIZE)
    patterns, basis, coef = ct.patterns_and_basis(system)
    sc = ct.build_scene("suzanne-wall")
    geom = ct.twin_geometry(sc, system, patterns)
    direct = ct.cycles_frames(sc, system, basis, samples=1, bounces=0, cache_dir=work)  # cached by the build
    H, W = SIZE[1], SIZE[0]
    lit = geom.lit.reshape(H, W).numpy()
    edge = edge_mask(geom)
    cyc_lit = direct["images"][0] > 1e-4
    assert np.mean((cyc_lit == lit)[~edge]) > 0.99
    stack = np.einsum("kb,bhw->khw", coef, direct["images"])
    both = lit & cyc_lit & ~edge
    phases = [ct.unit_phase(stack[j * ct.STEPS:(j + 1) * ct.STEPS]) for j in range(len(ct.FREQUENCIES))]
    Phi1 = phase_truth(geom, system.projector.size, "v", 1)[0]
    assert np.sqrt(np.mean(ct.wrap(phases[0] - Phi1)[both] ** 2)) < 2e-3   # rad: Cycles' geometry = the twin's
    for j, f in enumerate(ct.FREQUENCIES[1:], start=1):
        res = mf_unwrap([phases[0], phases[j]], (1.0, f), width=system.projector.width, valid=lit)
        Phi = phase_truth(geom, system.projector.size, "v", f)[0]
        # Blender samples the pattern image bilinearly: a ripple of a few mrad at 9.5-19 px periods
        assert np.sqrt(np.mean(ct.wrap(phases[j] - Phi)[both] ** 2)) < 1e-2
        # the true order relative to the measured phase (as the reader's order_true: a pixel whose
        # true wrapped phase is within the render's precision of +-pi may sit on either side)
        true = np.rint((np.nan_to_num(Phi) - phases[j]) / (2 * np.pi))
        assert int((np.asarray(res.order) != true)[both].sum()) == 0


@_cycles
def test_basis_synthesis_equals_a_direct_cycles_render_of_the_step(tiny):
    from synth.blender_twin import render_in_blender

    ct, work, r = tiny
    system = ct.testset_system(SIZE)
    patterns, basis, coef = ct.patterns_and_basis(system)
    sc = ct.build_scene("suzanne-wall")
    gi = ct.cycles_frames(sc, system, basis, samples=4, bounces=4, cache_dir=work)   # cached by the build
    ks = [ct.STEPS + 1, 2 * ct.STEPS + 7]                                           # f = 48 step 1, f = 96 step 7
    proj = np.stack([patterns[k].projector_image(system.projector.size, 0.5, 0.5) for k in ks])
    d_ref = float(np.linalg.norm(system.projector.center_world))
    out = render_in_blender(system, sc.meshes, proj, exposure=ct.EXPOSURE, reference_distance_mm=d_ref, samples=4,
                            bounces=4, seed=0, python=sys.executable)["images"]
    synth = np.einsum("kb,bhw->khw", coef[ks], gi["images"])
    assert out.max() > 0.05
    # exact (16-bit PNG steps, 1.5e-5, times the coefficients) at >= 98 % of the pixels (measured
    # 99.4-99.8 %); the rest differ by single-sample amounts, unbiased: Cycles terminates weak
    # light samples at random (its light threshold), which is not linear in the pattern value
    for k in range(len(ks)):
        same = np.abs(out[k] - synth[k]) < 1e-4
        assert same.mean() >= 0.98, same.mean()


# -- cheap parts (no Blender) ---------------------------------------------------------------------

def test_crop_keeps_the_focal_length_and_projects_like_the_full_camera():
    from calib import default_system
    from experiments.cycles_testset import testset_system

    full = default_system().ideal().camera
    s = testset_system((320, 240))
    x0, y0, W, H = s.meta["crop"]
    assert (W, H) == (320, 240) and s.camera.fx == full.fx
    P = np.array([[0.0, 0.0, 0.0], [20.0, -15.0, 10.0], [-30.0, 25.0, -20.0]])
    q = s.camera.project(P)
    q_full = full.project(P)
    assert np.allclose(q[:, 0], q_full[:, 0] - x0, atol=1e-9)
    # fy = fx (Blender's square pixels): rows agree to the fy / fx difference of the full camera
    assert np.allclose(q[:, 1], q_full[:, 1] - y0, atol=abs(full.fy / full.fx - 1) * 300 + 1e-9)


def test_every_step_is_a_combination_of_three_basis_images():
    from experiments.cycles_testset import FREQUENCIES, STEPS, patterns_and_basis, testset_system

    system = testset_system((64, 48))
    patterns, basis, coef = patterns_and_basis(system)
    assert basis.shape[0] == 1 + 2 * len(FREQUENCIES) and coef.shape == (STEPS * len(FREQUENCIES), basis.shape[0])
    imgs = np.stack([p.projector_image(system.projector.size, 0.5, 0.5) for p in patterns])
    assert np.abs(np.einsum("kb,bhw->khw", coef, basis.astype(np.float64)) - imgs).max() < 1e-5
    with pytest.raises(ValueError, match="multiple of 4"):
        patterns_and_basis(system, steps=6)


def test_wrong_pixel_context_counts_near_invalid_and_patches():
    from experiments.cycles_testset import wrong_pixel_context

    counted = np.ones((100, 100), bool)
    counted[:, :10] = False                        # an invalid band on the left
    wrong = np.zeros_like(counted)
    wrong[40:52, 12:22] = True                     # 120 px patch, 2-11 px from the band
    wrong[80, 90] = True                           # an isolated pixel far from it
    c = wrong_pixel_context(wrong, counted, radius=25)
    assert c["wrong"] == 121 and c["wrong_near"] == 120 and c["wrong_in_patches"] == 120
    assert c["counted_near"] == 100 * 25 and c["counted"] == 9000


def test_calib_eval_lays_out_the_cycles_section():
    from reports.learned_eval import markdown

    res = {"source": "t", "cycles": {48: {"Traditional": {"mf": {"ours": 0.10, "pixels": 100}},
                                          "DP-TPU (physics-aware)": {"mf": {"ours": 0.025, "pixels": 100}}}}}
    md = markdown(res)
    assert "## Cycles set" in md and "| 48 | DP-TPU (physics-aware) | 2.50 | 4.00x | 100 |" in md
