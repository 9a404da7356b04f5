"""The skull parity section's numbers (experiments.parity_evidence) and the pixel twin read once
(experiments.pixel_twin.measure_capture)."""
import math

import numpy as np
import pytest

from conftest import shared_data

TWO_PI = 2 * math.pi


def test_error_places_counts_components_edges_and_low_modulation():
    from experiments.parity_evidence import error_places

    H, W = 60, 80
    valid = np.ones((H, W), bool)
    valid[:, :10] = False                       # a shadow on the left
    lab = valid.copy()
    B = np.full((H, W), 0.2)
    B[40:, 40:] = 0.03                          # a dim corner
    wrong = np.zeros((H, W), bool)
    wrong[30, 12] = True                        # 3 px from the shadow (its last column is 9)
    wrong[30, 40] = wrong[31, 41] = True        # one 8-connected pair, far from it
    wrong[50, 50] = True                        # in the dim corner
    r = error_places(wrong, lab, valid, B, radius=5.0, low_modulation=0.05)
    assert (r["wrong"], r["components"], r["largest"], r["near_invalid"]) == (4, 3, 2, 1)
    assert r["labelled_near_invalid"] == pytest.approx(5 * H / lab.sum())   # columns 10-14
    assert r["low_B_labelled"] == 20 * 40 and r["low_B_rate"] == pytest.approx(1 / 800)
    assert r["median_B_wrong"] == pytest.approx(0.2) and r["median_B_labelled"] == pytest.approx(0.2)


def test_reference_suspects_tells_a_reference_error_from_a_decode_error():
    from experiments.parity_evidence import reference_suspects

    rng = np.random.default_rng(1)
    y, x = np.mgrid[0:40, 0:50].astype(np.float64)
    Phi = 3.0 + 0.3 * x + 0.1 * y + rng.normal(0.0, 0.05, x.shape)
    k = np.floor(Phi / TWO_PI).astype(np.int64)
    ph = Phi - TWO_PI * k
    ok = np.ones(x.shape, bool)
    ref, trad = k.copy(), k.copy()
    ref[10, 10] += 1                            # the reference is wrong here, the decode right
    trad[25, 30] -= 1                           # the decode is wrong here
    trad[5, 40] += 2
    ref[-1, -1] = -1                            # unlabelled: not counted
    trad[-1, -1] += 1
    r = reference_suspects(ph, trad, ref, ok)
    assert r["wrong"] == 3
    assert (r["reference"], r["traditional"], r["neither"], r["undecided"]) == (1, 2, 0, 0)
    assert r["reference_mask"][10, 10] and r["reference_mask"].sum() == 1
    assert r["margin_median"] < 0.1
    lone = np.zeros_like(ok)
    lone[25, 30] = True                          # no neighbour to fit a plane through
    assert reference_suspects(ph, trad, ref, lone)["undecided"] == 1


def test_fit_gamma_recovers_a_power_law_response_and_gamma_one_is_no_bias():
    from experiments.parity_evidence import fit_gamma, gamma_bias

    shifts = TWO_PI * np.arange(3) / 3
    u = np.random.default_rng(2).uniform(0, TWO_PI, 20_000)
    assert np.abs(gamma_bias(u, 1.0, shifts)).max() < 1e-9
    e13 = gamma_bias(u, 1.3, shifts)
    assert 0.02 < np.abs(e13).max() < 0.5       # a visible 3u ripple
    dev = e13 + 0.01 + np.random.default_rng(3).normal(0.0, 0.01, u.shape)
    r = fit_gamma(dev, u, shifts)
    assert r["gamma"] == pytest.approx(1.3, abs=0.015) and not r["at_edge"]
    assert r["offset"] == pytest.approx(0.01, abs=0.002) and r["rms"] < r["rms_gamma_1"]
    assert fit_gamma(np.random.default_rng(4).normal(0, 0.01, u.shape), u, shifts)["gamma"] == pytest.approx(1.0, abs=0.05)


def test_error_coincidence_against_chance():
    from experiments.parity_evidence import error_coincidence

    lab = np.ones((50, 50), bool)
    real = np.zeros_like(lab)
    real[25, 25] = True
    twin = np.zeros_like(lab)
    twin[25, 28] = twin[5, 5] = True
    r = error_coincidence(real, twin, lab, radius=5.0)
    assert (r["twin_wrong"], r["near"], r["fraction"]) == (2, 1, 0.5)
    disc = sum(1 for dy in range(-5, 6) for dx in range(-5, 6) if dx * dx + dy * dy <= 25)
    assert r["chance"] == pytest.approx(disc / 2500)


@pytest.mark.realdata
def test_skull_pixel_twin_read_once_is_the_same_file_and_matches_its_sensor(tmp_path):
    import h5py

    from experiments.parity_evidence import noise_match
    from experiments.pixel_twin import capture_sensor, measure_capture, pixel_twin
    from experiments.errors import ExperimentError
    from synth.export.capture import export_capture

    root = shared_data("slstudio-ps2x3-calib")
    folder, real = root / "skull_2x3", tmp_path / "skull.h5"
    export_capture(folder, real, reference_cloud=root / "skull_reference" / "pointCloud_from_skull_gray.mat",
                   reference_system=root / "calibration" / "calibration.xml")
    m = measure_capture(real, folder)
    sensor = capture_sensor(real, folder, measured=m)
    assert 2_000 < sensor["full_well_e"] < 40_000
    kw = dict(full_well_e=sensor["full_well_e"], read_noise_e=sensor["read_noise_e"], seed=0)
    a = pixel_twin(real, folder, tmp_path / "a.h5", measured=m, **kw)
    b = pixel_twin(real, folder, tmp_path / "b.h5", **kw)            # reads the capture again
    with h5py.File(a["file"]) as ha, h5py.File(b["file"]) as hb:
        for k in ("phase", "modulation", "flags", "reference_order"):
            assert np.array_equal(ha[f"v/{k}"][()], hb[f"v/{k}"][()]), k
    with pytest.raises(ExperimentError, match="measurement"):
        pixel_twin(b["file"], folder, tmp_path / "c.h5", measured=m, **kw)   # a measurement of another file
    t = measure_capture(a["file"])
    r = noise_match(m, t, full_well_e=sensor["full_well_e"], read_noise_e=sensor["read_noise_e"])
    assert len(r["true"]) == 10 and r["true_worst"] < 0.15     # the renderer's noise is its sensor's
    assert r["worst"] < 0.25                                   # and the capture's, per decile of A
    assert abs(r["pixel_sd"]["twin"] / r["pixel_sd"]["capture"] - 1) < 0.25


def test_moved_orders_counts_the_pixels_the_outlier_pass_moved():
    from experiments.parity_evidence import moved_orders
    from experiments.pixel_twin import CaptureMeasure

    shape = (8, 9)
    ph = np.full(shape, 1.0)
    kt, kr = np.full(shape, 3), np.full(shape, 3)
    kr[0, :] = -1                                 # unlabelled row: the traditional order counts
    lab = kr >= 0
    Phi = ph + TWO_PI * 3
    Phi[2, 2] -= TWO_PI                           # moved, labelled
    Phi[0, 4] += TWO_PI                           # moved, unlabelled
    Phi[5, 5] += 0.5                              # noise, not an order
    ok = np.ones(shape, bool)
    m = CaptureMeasure("x.h5", None, "v", None, Phi, np.zeros(shape), ok, lab, kr[None], [1.0, 16.0])
    d = {"phase_high": ph, "order_traditional": kt, "order_reference": kr, "labelled": lab}
    assert moved_orders(m, d) == {"decoded": 72, "moved": 2, "moved_labelled": 1}
