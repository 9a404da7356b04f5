"""The synthetic dataset keeps the reader's contract; the physics-aware inputs are frequency-free
and NaN-proof; the traditional order is exact without noise."""
import math

import numpy as np
import pytest
import torch

from unwrap.learned import features as Fe
from unwrap.learned.errors import ModelError
from unwrap.learned.losses import LossWeights, composite_loss
from unwrap.learned.synthetic import SyntheticFringeDataset, synthetic_sample

KEYS = {"prior", "phase_low", "phase_high", "modulation_low", "modulation_high", "order_traditional",
        "order_true", "valid", "frequency_low", "frequency_high", "index", "has_reference"}


@pytest.mark.parametrize("method,pair", [("mf", (1, 48)), ("mw", (47, 48)), ("nt", (47, 48))])
def test_synthetic_items_follow_the_reader_contract(method, pair):
    ds = SyntheticFringeDataset(2, size=(40, 56), method=method, frequencies=pair, seed=3)
    item = ds[1]
    assert set(item) == KEYS
    for key in ("prior", "phase_low", "phase_high", "modulation_low", "modulation_high"):
        assert item[key].shape == (1, 40, 56) and item[key].dtype == torch.float32
        assert torch.isfinite(item[key]).all()
        assert (item[key][0][~item["valid"]] == 0).all()
    for key in ("order_traditional", "order_true"):
        assert item[key].dtype == torch.int64 and item[key].shape == (40, 56)
        assert (item[key][~item["valid"]] == -1).all() and (item[key][item["valid"]] >= 0).all()
    assert item["valid"].dtype == torch.bool and 0.3 < item["valid"].float().mean() < 1.0
    assert float(item["frequency_high"]) == pair[1] and item["frequency_high"].dtype == torch.float64
    phi = item["phase_high"][0][item["valid"]]
    assert phi.min() >= -math.pi and phi.max() <= math.pi
    again = synthetic_sample(1, size=(40, 56), method=method, frequencies=pair, seed=3)
    assert np.array_equal(again["order_traditional"], item["order_traditional"].numpy())


@pytest.mark.parametrize("method,pair", [("mf", (1, 96)), ("mw", (95, 96)), ("nt", (95, 96)), ("mf", (1, 16))])
def test_traditional_order_is_exact_without_noise_or_bias(method, pair):
    s = synthetic_sample(0, size=(48, 64), method=method, frequencies=pair, noise=(0.0, 0.0), indirect=(0.0, 0.0),
                         subsurface=(0, 0), defocus=(0, 0))
    v = s["valid"]
    assert v.sum() > 1000
    assert np.array_equal(s["order_traditional"][v], s["order_true"][v])


def test_low_frequency_bias_makes_coherent_errors_that_noise_free_data_shows():
    """The bias alone (no noise) already makes MF at 48 wrong over regions; MW, whose beat comes
    from two high frequencies that the wide blur averages away, stays almost exact."""
    err = {}
    for method, pair in (("mf", (1, 48)), ("mw", (47, 48))):
        wrong = counted = 0
        for i in range(6):
            s = synthetic_sample(i, size=(64, 80), method=method, frequencies=pair, noise=(0, 0), indirect=(0.1, 0.1),
                                 subsurface=(0, 0), defocus=(0, 0))
            v = s["valid"]
            wrong += int((s["order_traditional"][v] != s["order_true"][v]).sum())
            counted += int(v.sum())
        err[method] = wrong / counted
    assert err["mf"] > 0.01 and err["mw"] < err["mf"] / 2


def test_physics_inputs_do_not_depend_on_the_absolute_frequency():
    """Without noise (8-bit quantisation only) the prior is near its rounding at every frequency; every channel is
    bounded the same way at 16 and 96 periods."""
    for pair in ((1, 16), (1, 48), (1, 96)):
        s = synthetic_sample(2, size=(48, 64), method="mf", frequencies=pair, noise=(0, 0), indirect=(0, 0),
                             subsurface=(0, 0), defocus=(0, 0))
        from unwrap.learned.synthetic import to_item
        b = torch.utils.data.default_collate([to_item(s)])
        x, ok = Fe.make_inputs(b, "physics")
        assert x.shape[1] == Fe.input_channels("physics")
        r2 = x[:, 0][ok].abs()                               # 2 r: ~0 up to 8-bit quantisation
        assert float(r2.median()) < 0.1
        assert float(x.abs().max()) <= 2.0


def test_nan_inputs_never_reach_the_network_or_the_loss():
    ds = SyntheticFringeDataset(2, size=(32, 48), method="mf", frequencies=(1, 48))
    b = torch.utils.data.default_collate([ds[0], ds[1]])
    b["method"] = torch.zeros(2, dtype=torch.int64)
    b["prior"][0, 0, 3:6, 4:9] = float("nan")
    b["phase_high"][1, 0, 10, :] = float("inf")
    b["modulation_low"][0, 0, 20, 20] = float("nan")
    assert b["valid"][0, 3:6, 4:9].all()                     # marked valid by mistake
    for kind in Fe.KINDS:
        x, ok = Fe.make_inputs(b, kind)
        assert torch.isfinite(x).all()
        assert not ok[0, 3:6, 4:9].any() and not ok[1, 10].any() and not ok[0, 20, 20]
        net = torch.nn.Conv2d(x.shape[1], Fe.output_channels(kind), 3, padding=1)
        out = net(x)
        t, m = Fe.targets(b, kind)
        assert not m[0, 3:6, 4:9].any()
        loss, parts = composite_loss(LossWeights(mse=1, fourier=1, ce=1), Fe.expected_map(out, kind), t, m,
                                     logits=out, classes=Fe.class_targets(b, kind))
        loss.backward()
        assert math.isfinite(float(loss.detach())) and all(math.isfinite(v) for v in parts.values())
        assert all(torch.isfinite(p.grad).all() for p in net.parameters())


def test_decode_keeps_orders_in_range_and_invalid_pixels_at_minus_one():
    ds = SyntheticFringeDataset(1, size=(32, 48), method="mf", frequencies=(1, 48))
    b = torch.utils.data.default_collate([ds[0]])
    logits = torch.zeros(1, 5, 32, 48)
    logits[:, 4] = 10.0                                      # +2 everywhere
    order, conf = Fe.decode(logits, b, "physics")
    v = b["valid"]
    assert (order[~v] == -1).all() and (order[v] <= 48).all() and (order[v] >= 0).all()
    assert torch.allclose(conf[v], torch.full_like(conf[v], conf[v].max()))


def test_bad_pairs_are_refused():
    with pytest.raises(ModelError, match="unit frequency"):
        SyntheticFringeDataset(1, method="mf", frequencies=(8, 48))
    with pytest.raises(ModelError, match="coprime"):
        SyntheticFringeDataset(1, method="nt", frequencies=(46, 48))
    with pytest.raises(ModelError, match="beat"):
        SyntheticFringeDataset(1, method="mw", frequencies=(40, 48))


def test_nt_pair_without_an_absolute_beat_gets_no_smoothed_order_channels():
    """(7, 96) is coprime but 89 periods apart: no coarse phase to filter, so the disagreement
    channels are 0 and the smoothed residual is the residue's own."""
    from unwrap.learned.data import MethodTagged
    ds = MethodTagged(SyntheticFringeDataset(1, size=(32, 48), method="nt", frequencies=(7, 96)), "nt")
    b = torch.utils.data.default_collate([ds[0]])
    x, ok = Fe.make_inputs(b, "physics")
    assert (x[:, 3:5] == 0).all()
    assert torch.equal(x[:, 1], x[:, 0]) and torch.equal(x[:, 2], x[:, 0])
