"""The learned path's CPU forward (:mod:`unwrap.learned.cpu_net`: channels-last, BatchNorm folded) and
the layouts around it: the same function as the plain network (orders equal up to float32 ties), the
caller's network untouched, features in (H, W, C) memory with the same values, a decode that gives
the softmax-argmax's bits in either logit layout, and the same-bits rewrites of the range check and
the coarse phase."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch import nn

from unwrap import _xp
from unwrap.learned import fast_features as FF
from unwrap.learned.checkpoint import load_model
from unwrap.learned.cpu_net import fold_batchnorm, prepare_for_cpu
from unwrap.learned.infer import fringe_period_px, unwrap_learned
from unwrap.learned.network import FringeUNet
from unwrap.learned.runtime import TorchPredictor, load_predictor, shipped_model_path
from unwrap.temporal import decode_pair

from test_learned_precision import _frame


def _bn_net(seed=0):
    torch.manual_seed(seed)
    net = FringeUNet(7, 5, width=8, depth=2, norm="batch", stem="strided")
    with torch.no_grad():                        # running statistics away from (0, 1): folding must use them
        for m in net.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.running_mean.uniform_(-0.5, 0.5)
                m.running_var.uniform_(0.5, 2.0)
                m.weight.uniform_(0.5, 1.5)
                m.bias.uniform_(-0.2, 0.2)
    return net.eval()


def test_folding_keeps_the_function_and_leaves_the_given_network_alone():
    net = _bn_net()
    n_bn = sum(isinstance(m, nn.BatchNorm2d) for m in net.modules())
    x = torch.randn(1, 7, 40, 56)                # not a multiple of 8: the network pads
    with torch.inference_mode():
        ref = net(x)
        fast = prepare_for_cpu(net, channels_last=True, fold=True)
        out = fast(x.contiguous(memory_format=torch.channels_last))
    assert not any(isinstance(m, nn.BatchNorm2d) for m in fast.modules())
    assert sum(isinstance(m, nn.BatchNorm2d) for m in net.modules()) == n_bn > 0
    assert net.enc[0][0].weight.is_contiguous()                 # the caller's weights stay NCHW
    assert torch.allclose(out, ref, atol=1e-4, rtol=1e-4) and not torch.equal(out, torch.zeros_like(out))
    g = FringeUNet(7, 5, width=8, depth=2).eval()               # GroupNorm: nothing to fold
    assert fold_batchnorm(g) == 0


def test_predictor_defaults_on_the_cpu_and_plain_for_a_callers_network():
    net, ck = load_model(shipped_model_path(), "cpu")
    p = TorchPredictor(net, ck)
    assert p.channels_last and p.input_layout == "nhwc" and p.multiple == 2 ** (ck["arch"]["depth"] + 1)
    assert p.fold_norm == (ck["arch"].get("norm") == "batch")
    assert p.net is net and any(isinstance(m, nn.BatchNorm2d) for m in net.modules()) == p.fold_norm
    q = load_predictor((net, ck))
    assert not q.channels_last and not q.fold_norm and q.input_layout == "nchw"
    assert load_predictor("learned").input_layout == "nhwc"
    assert load_predictor("learned", precision="bf16").input_layout == "nchw"


def test_a_network_in_train_mode_is_run_as_it_is():
    """No private folded copy of a network still being trained: its later weights are the ones run."""
    net, ck = load_model(shipped_model_path(), "cpu")
    net = _bn_net().train()
    p = TorchPredictor(net, dict(ck, arch=dict(ck["arch"], norm="batch", depth=2)))
    assert not p.fold_norm and not p.channels_last and p.input_layout == "nchw" and p._run is net
    assert net.training and any(isinstance(m, nn.BatchNorm2d) for m in net.modules())
    assert TorchPredictor(net.eval(), dict(ck, arch=dict(ck["arch"], norm="batch", depth=2))).fold_norm


def test_a_network_changed_after_the_predictor_was_made_is_the_one_run():
    """The predictor's private folded copy follows its network: fine-tuned in place (an optimiser
    step), given another state (load_state_dict), a tensor replaced, or put back in train mode."""
    _, ck = load_model(shipped_model_path(), "cpu")
    ck = dict(ck, arch=dict(ck["arch"], norm="batch", depth=2))
    net = _bn_net()
    p = TorchPredictor(net, ck)
    assert p.fold_norm and p.channels_last
    x = np.random.default_rng(3).standard_normal((1, 7, 40, 56)).astype(np.float32)

    def plain():
        with torch.inference_mode():
            return net(torch.from_numpy(x)).numpy()

    def same(a, b):
        return np.allclose(a, b, atol=1e-4, rtol=1e-4)

    before = p.logits(x)
    assert same(before, plain()) and p._run.copies == 1
    assert same(p.logits(x), before) and p._run.copies == 1           # nothing changed: no new copy
    opt = torch.optim.SGD(net.parameters(), lr=0.5)                   # one fine-tuning step, in place
    with torch.enable_grad(), torch.inference_mode(False):
        net(torch.from_numpy(x)).square().mean().backward()
    opt.step()
    assert not same(plain(), before)
    assert same(p.logits(x), plain()) and p._run.copies == 2
    net.load_state_dict(_bn_net(seed=1).state_dict())                  # BatchNorm statistics too
    assert same(p.logits(x), plain()) and p._run.copies == 3
    with torch.no_grad():
        net.enc[0][0].weight.data = net.enc[0][0].weight.data * 1.5      # a tensor replaced
    assert same(p.logits(x), plain()) and p._run.copies == 4
    net.train()                                                        # batch statistics: the network itself
    with torch.inference_mode():
        ref = net(torch.from_numpy(x)).numpy()
    assert same(p.logits(x), ref) and not same(ref, before)
    assert not any(isinstance(m, nn.BatchNorm2d) for m in p._run.copy.modules())


@pytest.mark.parametrize("size", [(96, 128), (90, 118)])
def test_channels_last_folded_path_gives_the_plain_orders_up_to_ties(size):
    phi, mods, valid, _ = _frame(*size)
    net, ck = load_model(shipped_model_path(), "cpu")
    plain = TorchPredictor(net, ck, channels_last=False, fold_norm=False)
    fast = TorchPredictor(net, ck)
    args = ("mf", phi[0], phi[1], mods[0], mods[1], valid, (1.0, 48.0))
    a = unwrap_learned(*args, width=912.0, model=plain, on_outside="ignore", log_probs=True)
    b = unwrap_learned(*args, width=912.0, model=fast, on_outside="ignore", log_probs=True)
    assert a.valid.mean() > 0.9 and np.array_equal(a.valid, b.valid)
    assert np.abs(a.log_probs - b.log_probs).max() < 1e-3
    s = np.sort(a.log_probs, axis=0)
    margin = s[-1] - s[-2]                      # log-probability gap = logit gap
    diff = a.order != b.order
    assert diff.sum() <= 2 and (not diff.any() or margin[diff].max() < 1e-3)
    assert np.abs(a.confidence - b.confidence).max() < 1e-4


def test_nhwc_features_hold_the_same_values_and_pad_with_zeros():
    phi, mods, valid, _ = _frame(50, 70)
    prior, trad, ok = decode_pair("mf", phi[0], phi[1], 1.0, 48.0, 912.0, valid)
    a, oka = FF.make_inputs("physics", "mf", prior, phi[0], phi[1], mods[0], mods[1], trad, ok, (1.0, 48.0))
    b, okb = FF.make_inputs("physics", "mf", prior, phi[0], phi[1], mods[0], mods[1], trad, ok, (1.0, 48.0),
                            layout="nhwc", multiple=16)
    assert a.flags.c_contiguous and not FF.is_nhwc(a) and FF.is_nhwc(b)
    assert b.shape == (1, a.shape[1], 64, 80) and np.array_equal(oka, okb)
    assert np.array_equal(b[..., :50, :70], a)
    assert not b[..., 50:, :].any() and not b[..., :, 70:].any()
    t = torch.from_numpy(b)                     # torch sees the layout without a copy
    assert t.is_contiguous(memory_format=torch.channels_last)
    assert FF.to_nhwc(b) is b and np.array_equal(FF.to_nhwc(a), a)
    with pytest.raises(ValueError, match="layout"):
        FF.make_inputs("physics", "mf", prior, phi[0], phi[1], mods[0], mods[1], trad, ok, (1.0, 48.0), layout="chw")


def _softmax_argmax(z, trad, ok, f_high, kind, K, wrap):
    """The decode as it was written once: softmax over the class axis, its first argmax."""
    z = np.asarray(z[0], dtype=np.float32)
    e = np.exp(z - z.max(axis=0, keepdims=True))
    p = e / e.sum(axis=0, keepdims=True)
    cls = p.argmax(axis=0)
    conf = np.take_along_axis(p, cls[None], axis=0)[0]
    kmax = int(math.floor(f_high + 0.5))
    order = trad + cls - K if kind == "physics" else cls.astype(np.int64)
    if wrap and kind == "physics":
        order = np.where(order < 0, order + wrap, np.where(order > kmax, order - wrap, order))
    order = np.clip(order, 0, kmax)
    return np.where(ok, order, -1), np.where(ok, conf, np.float32(0.0))


@pytest.mark.parametrize("kind,wrap", [("physics", None), ("physics", 48), ("prior_free", None)])
def test_decode_gives_the_softmax_argmax_bits_in_either_layout(kind, wrap):
    rng = np.random.default_rng(1)
    H, W = 48, 64
    z = (3 * rng.standard_normal((1, 5, H, W))).astype(np.float32)
    z[0, 3, :6] = z[0, 1, :6]                   # exact ties: the first class wins
    z[0, :, 6:9] = 0.0
    z[0, 2, 9:12] = z[0, 0, 9:12] + np.float32(1e-7)
    trad = rng.integers(-1, 49, (H, W))
    ok = rng.random((H, W)) > 0.1
    ref = _softmax_argmax(z, trad, ok, 48.0, kind, 2, wrap)
    cl = np.ascontiguousarray(z.transpose(0, 2, 3, 1)).transpose(0, 3, 1, 2)
    for zz, sl in ((z, np.s_[:, :]), (cl, np.s_[:, :]), (cl[..., :40, :50], np.s_[:40, :50]),
                   (z.astype(np.float64), np.s_[:, :])):
        r = _softmax_argmax(zz, trad[sl], ok[sl], 48.0, kind, 2, wrap) if zz.shape[-1] != W else ref
        order, conf = FF.decode(zz, trad[sl], ok[sl], 48.0, kind, 2, wrap)
        assert order.dtype == np.int64 and conf.dtype == np.float32
        assert np.array_equal(order, r[0]) and np.array_equal(conf, r[1])


def test_coarse_remainder_and_range_check_keep_their_bits():
    rng = np.random.default_rng(2)
    x = np.concatenate([rng.uniform(-2 * np.pi, 2 * np.pi, 5000),
                        [0.0, -0.0, 1e-300, -1e-300, np.nextafter(2 * np.pi, 0), -np.nextafter(2 * np.pi, 0)]])
    assert FF._remainder_2pi(x).tobytes() == np.remainder(x, 2 * np.pi).tobytes()      # -0.0 included
    y = np.concatenate([x, [7.0, -20.0, np.inf, np.nan]])      # outside the fast range: numpy's own
    with np.errstate(invalid="ignore"):
        assert np.array_equal(FF._remainder_2pi(y), np.remainder(y, 2 * np.pi), equal_nan=True)
    phi = rng.uniform(-np.pi, np.pi, (40, 50)) + np.linspace(0, 30, 50)
    phi = _xp.wrap(phi)
    v = rng.random((40, 50)) > 0.2
    # the period over the full frame, as it was computed once: differences everywhere, masked after
    gx, gy = _xp.wrap(np.diff(phi, axis=1)), _xp.wrap(np.diff(phi, axis=0))
    okx, oky = v[:, 1:] & v[:, :-1], v[1:, :] & v[:-1, :]
    g = np.hypot(np.where(okx[:-1, :], gx[:-1, :], 0.0), np.where(oky[:, :-1], gy[:, :-1], 0.0))
    ref = 2 * np.pi / float(np.median(g[okx[:-1, :] & oky[:, :-1]]))
    assert fringe_period_px(phi, v) == ref
    assert math.isnan(fringe_period_px(phi, np.zeros_like(v)))
