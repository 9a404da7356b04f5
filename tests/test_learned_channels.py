"""The network's input channel layout is one definition (unwrap.learned.channels): the numpy
features of inference and the torch features of training put every channel in the same place
for any set of smoothing windows, and ``input_channels`` counts what they write."""
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))


def test_the_layout_counts_every_channel_once():
    from unwrap.learned.channels import channel_groups, channel_slices, input_channels

    assert input_channels("physics") == 11 and input_channels("prior_free") == 12   # the shipped models
    for kind in ("physics", "prior_free"):
        for windows in ((7, 15), (9,), (5, 9, 21)):
            at = channel_slices(kind, windows)
            covered = sorted(i for s in at.values() for i in range(s.start, s.stop))
            assert covered == list(range(input_channels(kind, windows)))
            assert [n for n, _ in channel_groups(kind, windows)] == list(at)
    assert input_channels("physics", (5, 9, 21)) == 13


@pytest.mark.parametrize("windows", [(5, 9, 21), (11,)])
def test_numpy_and_torch_features_agree_for_other_windows(windows):
    import torch

    from test_learned_deploy import _scene, _torch_batch
    from unwrap.learned import fast_features as FF
    from unwrap.learned import features as Fe
    from unwrap.learned.channels import channel_slices, input_channels

    method, freqs = "mf", (1, 48)
    s, prior, order_trad, valid = _scene(method, freqs, size=(80, 100))
    batch = _torch_batch(method, s, prior, order_trad, valid, freqs)
    x_old, ok_old = Fe.make_inputs(batch, "physics", windows=windows)
    x_new, ok_new = FF.make_inputs("physics", method, prior, s["phase_low"], s["phase_high"], s["modulation_low"],
                                   s["modulation_high"], order_trad, valid, freqs, windows=windows)
    assert x_new.shape == tuple(x_old.shape) == (1, input_channels("physics", windows), *valid.shape)
    assert np.array_equal(ok_new, ok_old[0].numpy())
    # pixels whose prior or a smoothed prior is a float32 tie may round either way
    okt = torch.from_numpy(ok_new)[None]
    near = np.zeros(ok_new.shape, bool)
    for p in [batch["prior"].double()] + [Fe.smoothed_prior(batch, okt, w)[0].double() for w in windows]:
        frac = (p - torch.floor(p)).numpy()[0, 0]
        near |= np.abs(frac - 0.5) < 1e-4
    assert float(near.mean()) < 0.01
    diff = np.abs(x_new - x_old.numpy())[0]
    for c in range(x_new.shape[1]):
        bad = (diff[c] > 2e-5) & ~near
        assert not bad.any(), (windows, c, int(bad.sum()), float(diff[c].max()))
    # the channels do differ between windows (the test would see a misplaced one)
    at = channel_slices("physics", windows)
    sm = x_new[0, at["smoothed"]]
    assert np.all(sm.std(axis=(1, 2)) > 0) and np.all(x_new[0, at["valid"]] == ok_new)
    if len(windows) > 1:
        assert not np.allclose(sm[0], sm[-1])
