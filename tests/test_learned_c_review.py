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
