"""unwrap.streamed_write: ``unwrap.h5`` and the previews built orientation by orientation while the
capture is decoded are the files ``write_results`` writes; a capture that fails half way writes
nothing; ``calib unwrap --model`` goes through it."""
import math

import h5py
import numpy as np
import pytest

from unwrap.pipeline import OrientationResult, write_results
from unwrap.streamed_write import StreamedWrite
from unwrap.temporal import Unwrapped


def _result(o, H=150, W=260, seed=0):
    """An orientation result with every map ``calib unwrap --model`` writes (noisy float64 maps:
    stored and deflated byte planes; NaN holes; extras as the learned path adds them)."""
    rng = np.random.default_rng(seed)
    x = np.tile(np.arange(W, dtype=np.float64), (H, 1))
    f = 8.0
    phase = 2 * math.pi * f * x / W + rng.normal(0, 1e-3, (H, W))
    valid = rng.random((H, W)) > 0.05
    order = np.where(valid, np.floor(phase / (2 * math.pi)).astype(np.int32), -1)
    u = Unwrapped(np.where(valid, phase, np.nan), order, valid, phase / (2 * math.pi) + rng.normal(0, 0.01, (H, W)),
                  f, "mf+learned")
    r = OrientationResult(o, float(W), u, 50.0 + rng.random((H, W)), np.full((H, W), 100.0))
    r.extras = {"confidence": rng.random((H, W)).astype(np.float32), "order_traditional": order.copy()}
    return r


def _datasets(path):
    with h5py.File(path, "r") as f:
        out = {"/": dict(f.attrs)}
        f.visititems(lambda n, d: out.__setitem__(n, (d[()].tobytes(), d.dtype.str, d.shape, d.compression,
                                                      d.shuffle) if isinstance(d, h5py.Dataset)
                                                  else {k: np.asarray(v).tolist() for k, v in d.attrs.items()}))
    return out


def test_streamed_file_and_previews_are_write_results_files(tmp_path):
    results = {"v": _result("v", seed=1), "h": _result("h", seed=2)}
    ref = write_results(results, tmp_path / "ref", attrs={"capture": "c"}, previews_beside=False)
    w = StreamedWrite(tmp_path / "new", attrs={"capture": "c"})
    for o, r in results.items():
        w.add(o, r)
    path = w.close()
    assert path == tmp_path / "new" / "unwrap.h5"
    assert _datasets(path) == _datasets(ref)                        # every dataset bitwise, same filters
    assert path.read_bytes() == ref.read_bytes()                    # and the very same file
    for o in results:
        assert (tmp_path / "new" / f"{o}_unwrap.png").read_bytes() == (tmp_path / "ref" / f"{o}_unwrap.png").read_bytes()
    assert sorted(p.name for p in (tmp_path / "new").iterdir()) == ["h_unwrap.png", "unwrap.h5", "v_unwrap.png"]


def test_no_previews_and_an_abandoned_capture_write_nothing_more(tmp_path):
    w = StreamedWrite(tmp_path / "a", previews=False)
    w.add("v", _result("v"))
    w.close()
    assert [p.name for p in (tmp_path / "a").iterdir()] == ["unwrap.h5"]
    w = StreamedWrite(tmp_path / "b")
    w.add("v", _result("v"))
    w.abandon()                         # the next orientation failed: no file, no temporary
    assert not (tmp_path / "b").exists() or not list((tmp_path / "b").iterdir())
    with pytest.raises(RuntimeError):
        w.add("h", _result("h"))


def test_a_group_that_fails_to_write_is_raised_by_close(tmp_path):
    w = StreamedWrite(tmp_path / "c", previews=False)
    w.add("x", _result("v"))            # not an orientation of the layout: write_phase_group refuses it
    w.add("h", _result("h"))
    with pytest.raises(ValueError, match="orientation"):
        w.close()
    assert not (tmp_path / "c").exists() or not list((tmp_path / "c").iterdir())
