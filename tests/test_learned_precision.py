"""Where and in what arithmetic the learned network runs (``load_predictor(device=, precision=)``,
``calib unwrap --device / --precision``): half precision moves an order only where two classes'
logits tie, fp16 and a missing CUDA device are refused with a message, and on a CUDA device (only
where one exists) the orders equal the CPU's up to such ties."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from unwrap.learned import fast_features as FF
from unwrap.learned.errors import ModelError
from unwrap.learned.infer import unwrap_learned
from unwrap.learned.runtime import load_predictor
from unwrap.patterns import fringe_intensity
from unwrap.phase_shift import wrapped_phase
from unwrap.temporal import decode_pair

CUDA = torch.cuda.is_available()


def _frame(H=96, W=128, seed=3):
    """A noisy MF 1/48 frame (12 steps) of a tilted plane with a step: (phases, modulations, valid, true order)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W]
    u = 150 + (600.0 / W) * xx + 0.3 * yy + np.where(xx > W // 2, 37.0, 0.0)   # projector column, px of 912
    phi, mods, valid = [], [], np.ones((H, W), bool)
    for f in (1, 48):
        Phi = 2 * np.pi * f * u / 912
        st = np.clip(np.rint(255 * np.stack([fringe_intensity(Phi, n, 12, 0.45, 0.3) for n in range(12)])
                             + rng.normal(0, 3, (12, H, W))), 0, 255).astype(np.uint8)
        w = wrapped_phase(st)
        phi.append(np.nan_to_num(w.phase))
        mods.append(w.B / 255.0)
        valid &= w.valid
    k = np.rint((2 * np.pi * 48 * u / 912 - phi[1]) / (2 * np.pi)).astype(np.int64)
    return phi, mods, valid, k


def _orders(pred, phi, mods, valid):
    prior, trad, ok = decode_pair("mf", phi[0], phi[1], 1.0, 48.0, 912.0, valid)
    x, ok = FF.make_inputs(pred.arch["kind"], "mf", prior, phi[0], phi[1], mods[0], mods[1], trad, ok, (1.0, 48.0))
    z = pred.logits(pred.prepare(x) if hasattr(pred, "prepare") else x)[..., :x.shape[-2], :x.shape[-1]]
    order, _ = FF.decode(z, trad, ok, 48.0, pred.arch["kind"], int(pred.arch["max_correction"]))
    s = np.sort(z[0], axis=0)
    return order, ok, s[-1] - s[-2]


def test_bf16_on_the_cpu_moves_orders_only_where_the_logits_tie():
    phi, mods, valid, _ = _frame()
    o32, ok, margin = _orders(load_predictor("learned", device="cpu"), phi, mods, valid)
    o16, ok16, _ = _orders(load_predictor("learned", device="cpu", precision="bf16"), phi, mods, valid)
    assert np.array_equal(ok, ok16) and ok.mean() > 0.9
    diff = ok & (o32 != o16)
    assert diff.mean() < 0.005
    # bfloat16 keeps 8 bits of mantissa: a logit of ~10 moves by ~0.05, and features more; a pixel
    # whose order moves had its two best classes within a fraction of a logit of each other
    assert not diff.any() or margin[diff].max() < 1.0
    assert np.median(margin[ok]) > 3.0


def test_the_learned_path_takes_a_predictor_in_any_precision():
    phi, mods, valid, k = _frame()
    args = ("mf", phi[0], phi[1], mods[0], mods[1], valid, (1, 48))
    r32 = unwrap_learned(*args, width=912, model=load_predictor("learned", device="cpu"), on_outside="ignore")
    r16 = unwrap_learned(*args, width=912, model=load_predictor("learned", device="cpu", precision="bf16"),
                         on_outside="ignore")
    ok = r32.valid
    assert (r32.order[ok] == k[ok]).mean() > 0.99
    assert (r16.order[ok] == r32.order[ok]).mean() > 0.995


def test_the_on_device_path_gives_the_numpy_paths_orders(monkeypatch):
    """What a CUDA predictor runs (the training's torch features and decode on the device), here on
    the CPU: the orders of the numpy path up to float32 ties, the same confidence."""
    from unwrap.learned.runtime import TorchPredictor

    phi, mods, valid, k = _frame()
    mods[1][5, 7], mods[0][40, 60] = np.inf, np.nan      # an infinite input drops the pixel on both paths
    args = ("mf", phi[0], phi[1], mods[0], mods[1], valid, (1, 48))
    pred = load_predictor("learned", device="cpu")
    r_np = unwrap_learned(*args, width=912, model=pred, on_outside="ignore")
    monkeypatch.setattr(TorchPredictor, "features_on_device", property(lambda self: True))
    r_dev = unwrap_learned(*args, width=912, model=pred, on_outside="ignore")
    assert np.array_equal(r_np.valid, r_dev.valid) and np.array_equal(r_np.order < 0, r_dev.order < 0)
    assert r_dev.order[5, 7] == -1 and r_dev.valid[5, 7]
    same = r_np.order == r_dev.order
    assert same.mean() > 0.999 and (r_dev.order[r_dev.valid] == k[r_dev.valid]).mean() > 0.99
    np.testing.assert_allclose(r_dev.confidence[same], r_np.confidence[same], atol=2e-4)
    assert r_dev.order.dtype == np.int64 and r_dev.confidence.dtype == np.float32
    assert np.all(r_dev.order[~r_dev.valid] == -1)


def test_unsupported_devices_and_precisions_are_refused_by_name():
    with pytest.raises(ModelError, match="fp16 needs a CUDA device"):
        load_predictor("learned", device="cpu", precision="fp16")
    with pytest.raises(ModelError, match="precision 'fp8'"):
        load_predictor("learned", precision="fp8")
    with pytest.raises(ModelError, match="device 'tpu'"):
        load_predictor("learned", device="tpu")
    with pytest.raises(ModelError, match="an ONNX model runs in float32"):
        load_predictor("whatever.onnx", precision="bf16")
    assert load_predictor("learned") is load_predictor("learned", device="cpu")      # one model loaded once
    if not CUDA:
        with pytest.raises(ModelError, match="torch sees no CUDA device"):
            load_predictor("learned", device="cuda")
        assert load_predictor("learned", device="auto").device.type == "cpu"


def test_calib_unwrap_device_and_precision_options_are_checked(tmp_path, capsys):
    from sltwin.cli import main
    from test_cli_bad_inputs import _write_capture

    _write_capture(tmp_path / "cap")
    bad = [(["--device", "cpu"], "--device / --precision belong to --model"),
           (["--precision", "bf16"], "--device / --precision belong to --model"),
           (["--model", "learned", "--precision", "fp16", "--device", "cpu"], "fp16 needs a CUDA device")]
    if not CUDA:
        bad.append((["--model", "learned", "--device", "cuda"], "torch sees no CUDA device"))
    for args, msg in bad:
        capsys.readouterr()
        assert main(["unwrap", str(tmp_path / "cap"), *args, "-o", str(tmp_path / "x"), "--no-previews", "-q"]) == 2
        err = capsys.readouterr().err
        assert msg in err and "Traceback" not in err, args
    assert not (tmp_path / "x").exists()
    assert main(["unwrap", str(tmp_path / "cap"), "--model", "learned", "--device", "auto", "--precision", "bf16",
                 "-o", str(tmp_path / "ok"), "--no-previews", "-q"]) == 0
    assert (tmp_path / "ok" / "unwrap.h5").is_file()


@pytest.mark.skipif(not CUDA, reason="no CUDA device (the GPU rows: python -m bench.learned_gpu)")
def test_on_cuda_the_orders_equal_the_cpus_up_to_ties():
    phi, mods, valid, k = _frame(240, 320)
    o_cpu, ok, margin = _orders(load_predictor("learned", device="cpu"), phi, mods, valid)
    for prec, most in (("fp32", 1e-4), ("fp16", 5e-3), ("bf16", 5e-3)):
        o, ok2, _ = _orders(load_predictor("learned", device="cuda", precision=prec), phi, mods, valid)
        assert np.array_equal(ok, ok2)
        diff = ok & (o != o_cpu)
        assert diff.mean() <= most, prec
        assert not diff.any() or margin[diff].max() < (0.05 if prec == "fp32" else 1.0), prec
    r_cpu = unwrap_learned("mf", phi[0], phi[1], mods[0], mods[1], valid, (1, 48), width=912,
                           model=load_predictor("learned", device="cpu"), on_outside="ignore")
    r = unwrap_learned("mf", phi[0], phi[1], mods[0], mods[1], valid, (1, 48), width=912,
                       model=load_predictor("learned", device="cuda"), on_outside="ignore")
    assert (r.order[r.valid] == k[r.valid]).mean() > 0.99
    assert (r.order == r_cpu.order).mean() > 0.999          # features and decode on the GPU: ties only
