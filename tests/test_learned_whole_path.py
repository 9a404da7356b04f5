"""The learned path around the forward (docs/speed.md, "Session 11: whole path"): the C replica of the
MF pair's decode, of the input features and of the decoding (unwrap/learned/_features_c.py) give the
numpy code's bits, on one thread and split over two; the plane fits' boxes on two threads give the
bits of one; the range check's row sample keeps the full frame's decision."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tests.conftest import shared_data
from unwrap.learned import _features_c as FC
from unwrap.learned import fast_features as FF
from unwrap.learned import infer as I
from unwrap.temporal import decode_pair

needs_c = pytest.mark.skipif(FF.native_features() is None, reason="no C compiler: the numpy code runs (tested elsewhere)")


def _frame(H, W, seed=0):
    """A noisy MF (1, 48) ramp with holes, NaN and infinities (what the path sees at its worst)."""
    rng = np.random.default_rng(seed)
    u = np.tile(np.linspace(50, 850, W), (H, 1)) + rng.normal(0, 0.4, (H, W))
    plo = np.angle(np.exp(1j * (2 * np.pi * u / 912 + rng.normal(0, 0.02, (H, W)))))
    phi = np.angle(np.exp(1j * (2 * np.pi * 48 * u / 912 + rng.normal(0, 0.1, (H, W)))))
    ml, mh = rng.uniform(0.0, 0.6, (H, W)), rng.uniform(0.0, 0.6, (H, W)).astype(np.float32)
    valid = rng.random((H, W)) > 0.1
    plo[3, :3], phi[4, :3] = [np.nan, np.inf, -0.0], [-np.inf, np.nan, 0.0]
    ml[5, :3], mh[6, :2] = [np.nan, 1e39, -0.0], [np.inf, np.nan]
    return plo, phi, ml, mh, valid & np.isfinite(plo) & np.isfinite(phi)


SIZES = [(21, 19), (230, 190)]        # one call; two row ranges on threads (>= SPLIT_MIN_PIX)
assert SIZES[0][0] * SIZES[0][1] < FC.SPLIT_MIN_PIX <= SIZES[1][0] * SIZES[1][1]


@needs_c
@pytest.mark.parametrize("size", SIZES)
def test_mf_pair_decode_is_decode_pairs(size):
    plo, phi, _, _, v = _frame(*size)
    want = decode_pair("mf", np.nan_to_num(plo), np.nan_to_num(phi), 1.0, 48.0, 912.0, v)
    got = FC.mf_prior(plo, phi, v, 1.0, 48.0, 912.0, FF.native_features())
    for a, b in zip(want, got):
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes()
    assert I._decode_pair("mf", plo, phi, 1.0, 48.0, 912.0, v)[0].tobytes() == want[0].tobytes()
    with pytest.raises(ValueError):                 # mf_unwrap's own checks still run
        FC.mf_prior(plo, phi, v, 2.0, 48.0, 912.0, FF.native_features())


@needs_c
@pytest.mark.parametrize("size", SIZES)
@pytest.mark.parametrize("layout,multiple", [("nhwc", 1), ("nhwc", 16), ("nchw", 1), ("nchw", 8)])
def test_features_are_the_numpy_features(size, layout, multiple):
    plo, phi, ml, mh, v = _frame(*size, seed=1)
    prior, trad, ok = decode_pair("mf", np.nan_to_num(plo), np.nan_to_num(phi), 1.0, 48.0, 912.0, v)
    prior[7, :3] = [np.nan, 0.5, -0.5]
    with np.errstate(over="ignore", invalid="ignore"):
        a, oka = FF.make_inputs("physics", "mf", prior, plo, phi, ml, mh, trad, ok, (1.0, 48.0), layout=layout,
                                multiple=multiple, native=False)
    b, okb = FF.make_inputs("physics", "mf", prior, plo, phi, ml, mh, trad, ok, (1.0, 48.0), layout=layout,
                            multiple=multiple)
    assert a.shape == b.shape and a.strides == b.strides and FF.is_nhwc(b) == (layout == "nhwc")
    assert np.array_equal(a.view(np.uint32), b.view(np.uint32))        # every bit, signed zeros included
    assert np.array_equal(oka, okb)


def test_features_outside_the_c_code_run_numpy(monkeypatch):
    """Integer maps (a cast through float64 may round otherwise), float orders, MW and no library: the
    numpy code."""
    plo, phi, ml, mh, v = _frame(21, 19, seed=2)
    prior, trad, ok = decode_pair("mf", np.nan_to_num(plo), np.nan_to_num(phi), 1.0, 48.0, 912.0, v)
    called = []
    monkeypatch.setattr(FC, "make_inputs", lambda *a, **k: called.append(1))
    mi = np.full(ml.shape, 3, np.int64)
    with np.errstate(over="ignore", invalid="ignore"):
        FF.make_inputs("physics", "mf", prior, plo, phi, mi, mh, trad, ok, (1.0, 48.0))
        FF.make_inputs("physics", "mw", prior, plo, phi, ml, mh, trad, ok, (47.0, 48.0))
        FF.make_inputs("physics", "mf", prior, plo, phi, ml, mh, trad + 0.25, ok, (1.0, 48.0))
        monkeypatch.setattr(FF, "native_features", lambda: None)
        FF.make_inputs("physics", "mf", prior, plo, phi, ml, mh, trad, ok, (1.0, 48.0))
    assert not called
    assert not FC.covered(mi) and FC.covered(ml, mh)
    assert FC.integral(trad) and FC.integral(trad.astype(np.uint16)) and not FC.integral(trad + 0.25)


@needs_c
@pytest.mark.parametrize("size", SIZES)
@pytest.mark.parametrize("kind", ["physics", "prior_free"])
def test_decoding_is_the_numpy_decoding(size, kind):
    H, W = size
    rng = np.random.default_rng(3)
    z = rng.normal(0.0, 3.0, (1, 5, H, W)).astype(np.float32)
    z[0, :, 0, :4] = 1.0                                        # ties: the first class wins
    z[0, 1, 1, 1] = np.nan
    trad = rng.integers(0, 49, (H, W))
    ok = rng.random((H, W)) > 0.1
    cl = np.ascontiguousarray(z.transpose(0, 2, 3, 1)).transpose(0, 3, 1, 2)
    for logits, sl in ((z, np.s_[:, :]), (cl, np.s_[:, :]), (cl[..., :H - 3, :W - 2], np.s_[:H - 3, :W - 2])):
        a = FF.decode(logits, trad[sl], ok[sl], 48.0, kind, 2, None, native=False)
        b = FF.decode(logits, trad[sl], ok[sl], 48.0, kind, 2, None)
        assert a[0].dtype == b[0].dtype == np.int64 and a[1].dtype == b[1].dtype == np.float32
        assert a[0].tobytes() == b[0].tobytes() and a[1].tobytes() == b[1].tobytes()


def test_plane_fit_boxes_on_two_threads_are_one_threads():
    plo, _, _, _, v = _frame(200, 180, seed=4)
    Phi = FF.coarse_phase("mf", np.nan_to_num(plo), np.nan_to_num(plo), 1.0, 48.0)[0]
    assert Phi.size >= FF.THREAD_MIN_PIX
    both = FF.plane_filter(Phi, v, (7, 15))
    for w in (7, 15):
        assert both[w].tobytes() == FF.plane_filter(Phi, v, (w,))[w].tobytes()


def test_range_check_sample_keeps_the_value_and_the_decision():
    """The 640 x 480 speed ramp: the sampled period within 0.5 % of the frame's; a frame near the
    3 px threshold is measured over every row (the same value, the same decision); too few sampled
    pairs: every row."""
    from experiments.learned_evaluation import speed_scene

    _, phi, _, valid = speed_scene((480, 640))
    full, sample = I.fringe_period_px(phi[1], valid), I.measured_period_px(phi[1], valid)
    assert sample != full and abs(sample / full - 1) < 5e-3
    rng = np.random.default_rng(5)
    x = np.arange(320.0)[None, :] + rng.normal(0, 0.05, (240, 320))
    for period in (2.5, 3.1, 3.6):                      # inside the band: the full frame's value
        near = np.angle(np.exp(2j * np.pi * x / period))
        v = np.ones(near.shape, bool)
        p = I.measured_period_px(near, v)
        assert p == I.fringe_period_px(near, v)
        meta = {"frequencies": {"mf": (1, 48)}}
        status = I.check_frequency_range(meta, "mf", (1, 48), near, v, on_outside="ignore")["status"]
        assert (status == "refused") == (p < I.MIN_PERIOD_PX)
    far = np.angle(np.exp(2j * np.pi * x / 12.0))
    p = I.measured_period_px(far, np.ones(far.shape, bool))
    assert p != I.fringe_period_px(far, np.ones(far.shape, bool)) and abs(p / 12.0 - 1) < 0.02
    small = far[:40, :50]                               # 10 sampled rows x 49 pairs < PERIOD_MIN_SAMPLES
    assert I.fringe_period_px(small, np.ones(small.shape, bool), I.PERIOD_ROW_STEP) == \
        I.fringe_period_px(small, np.ones(small.shape, bool))


def _real_high_phases():
    """(name, wrapped high phase, valid) of the pyramid's two orientations (f = 16) and the SLStudio
    skull (the learned capture path's own phase, recorded from its range check)."""
    import cv2

    from unwrap.learned.capture import unwrap_capture_learned
    from unwrap.phase_shift import wrapped_phase

    out = []
    root = shared_data("thomriiii-pyramid-mf-1-4-16", "structured")
    for name in ("vertical", "horizontal"):
        st = np.stack([cv2.imread(str(root / name / "f_016" / f"step_{k:03d}.png"), cv2.IMREAD_GRAYSCALE)
                       for k in range(8)])
        w = wrapped_phase(st, -2 * np.pi * np.arange(8) / 8, min_modulation=0.02 * 255)
        out.append((f"pyramid {name}", np.nan_to_num(w.phase), w.valid))
    seen = []
    real = I.measured_period_px
    I.measured_period_px = lambda phase, valid: seen.append((phase, valid)) or real(phase, valid)
    try:
        unwrap_capture_learned(shared_data("slstudio-ps2x3-calib") / "skull_2x3", "mf")
    finally:
        I.measured_period_px = real
    return out + [(f"skull {i}", p, v) for i, (p, v) in enumerate(seen)]


@pytest.mark.realdata
def test_range_check_sample_on_real_captures():
    """The sampled period of real captures within 1 % of the full frame's (measured with the staggered
    rows: 0.01-0.77 %; rows 0, 4, 8, ...: 0.17-0.36 %), the same decision."""
    frames = _real_high_phases()
    assert len(frames) == 3
    for name, phase, valid in frames:
        full, sample = I.fringe_period_px(phase, valid), I.measured_period_px(phase, valid)
        assert sample != full and abs(sample / full - 1) < 1e-2, (name, full, sample)
        assert (sample < I.MIN_PERIOD_PX) == (full < I.MIN_PERIOD_PX)


@needs_c
def test_whole_path_is_the_numpy_paths(monkeypatch):
    """unwrap_learned with the C stages gives the orders, confidences, priors of the numpy stages."""
    plo, phi, ml, mh, v = _frame(96, 128, seed=6)
    args = ("mf", plo, phi, ml, mh, v, (1.0, 48.0))
    a = I.unwrap_learned(*args, width=912.0, on_outside="ignore")
    monkeypatch.setattr(FC, "_LIB", [None])
    with np.errstate(over="ignore", invalid="ignore"):
        b = I.unwrap_learned(*args, width=912.0, on_outside="ignore")
    for x, y in ((a.order, b.order), (a.confidence, b.confidence), (a.prior, b.prior),
                 (a.order_traditional, b.order_traditional), (a.valid, b.valid)):
        assert x.tobytes() == y.tobytes()
    assert math.isfinite(a.frequency_check["period_px"])


def test_a_library_with_other_bits_is_not_used(monkeypatch):
    """The per-process check refuses a library whose decoding differs by one bit."""
    if FF.native_features() is None:
        pytest.skip("no C compiler")
    funcs = dict(FF.native_features())
    real = funcs["decode2"]

    def off_by_one(D, K, HW, i0, i1, trad, ok, phys, shift, kmax, order, conf):
        real(D, K, HW, i0, i1, trad, ok, phys, shift, kmax + 1, order, conf)
    funcs["decode2"] = off_by_one
    assert not FC._same_bits(funcs, FF)
    assert FC._same_bits(dict(FF.native_features()), FF)
