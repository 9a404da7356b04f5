"""Review of the learned path's C stages (session 11): inputs outside what the C code reads."""
from __future__ import annotations

import numpy as np
import pytest

from unwrap.learned import fast_features as FF

needs_c = pytest.mark.skipif(FF.native_features() is None, reason="no C compiler: the numpy code runs (tested elsewhere)")


@needs_c
def test_decode_with_other_shapes_is_the_numpy_decoding():
    """ok / traditional orders of another shape than the logits' planes: numpy's error, not a C read
    past their end; a prior-free model's decoding takes no traditional orders (None), as numpy's."""
    z = np.random.default_rng(0).normal(0.0, 3.0, (1, 5, 6, 7)).astype(np.float32)
    ok = np.ones((6, 7), bool)
    want = FF.decode(z, None, ok, 16.0, "prior_free", 2, None, native=False)
    got = FF.decode(z, None, ok, 16.0, "prior_free", 2, None)
    assert all(a.tobytes() == b.tobytes() for a, b in zip(want, got))
    with pytest.raises((ValueError, IndexError)):
        FF.decode(z, np.zeros((2, 3), np.int64), np.ones((2, 3), bool), 16.0, "physics", 2, None)
    with pytest.raises((ValueError, IndexError)):
        FF.decode(z, np.zeros((6, 7), np.int64), np.ones((2, 3), bool), 16.0, "prior_free", 2, None)


def _ramp(period: float, shape=(480, 640)) -> np.ndarray:
    x = np.arange(shape[1], dtype=np.float64)[None, :].repeat(shape[0], 0)
    return np.angle(np.exp(2j * np.pi * x / period))


def test_range_check_sample_sees_a_defect_every_4th_row_as_the_frame_does():
    """A defect that repeats every 4th row (rows 0, 4, 8, ... alternating by pi: a sensor's bad row
    pattern, a 2x2 mosaic) weighs in the sample as in the frame: before, the sample read only rows
    0, 4, 8, ..., so 8 px fringes were measured at 1.8 px and refused as aliased; and fringes clean
    only on rows 4k, 4k + 1 (aliased elsewhere) passed the check at 8 px where the frame reads < 3 px."""
    from unwrap.learned import infer as I

    phi = _ramp(8.0)
    v = np.ones(phi.shape, bool)
    bad = phi.copy()
    bad[0::4] = (np.arange(phi.shape[1]) % 2) * np.pi * 0.999
    full = I.fringe_period_px(bad, v)
    assert full > I.MIN_PERIOD_PX
    assert I.measured_period_px(bad, v) > I.MIN_PERIOD_PX
    meta = {"frequencies": {"mf": (1, 48)}}
    assert I.check_frequency_range(meta, "mf", (1, 48), bad, v, on_outside="ignore")["status"] != "refused"
    aliased = np.where((np.arange(phi.shape[0]) % 4 < 2)[:, None], phi, (np.arange(phi.shape[1]) % 2) * np.pi * 0.999)
    assert I.fringe_period_px(aliased, v) < I.MIN_PERIOD_PX
    assert I.measured_period_px(aliased, v) < I.MIN_PERIOD_PX
    assert I.check_frequency_range(meta, "mf", (1, 48), aliased, v, on_outside="ignore")["status"] == "refused"


@needs_c
def test_the_c_features_refuse_more_windows_than_their_row_buffers_hold():
    """features2 keeps MAX_WINDOWS row buffers: a direct call with more windows is refused before any C
    runs (the public make_inputs sends more to the numpy code)."""
    from unwrap.learned import _features_c as FC

    windows = tuple(range(3, 3 + 2 * (FC.MAX_WINDOWS + 1), 2))
    m = np.zeros((4, 4))
    with pytest.raises(ValueError, match="at most"):
        FC.make_inputs(m, m, m, m, m, np.zeros((4, 4), np.int64), np.ones((4, 4), bool), (1.0, 16.0), windows,
                       layout="nhwc", multiple=1, plane_filters=None, coarse=(1.0, 0.5), F=None)


@needs_c
def test_the_per_process_check_crosses_the_c_loops_chunks():
    """The library's check runs a frame whose rows are wider than the C loops' 512-pixel chunks (the
    user's own compiler's code at a chunk boundary, not only the tests' machine's), and it passes."""
    from unwrap.learned import _features_c as FC

    assert any(W > 512 for _, _, W in FC.CHECK_FRAMES) and "#define CH 512" in FC._SOURCE
    assert FC._same_bits(FF.native_features(), FF)
