"""Losses, network, checkpoints and configs of the learned unwrapping: the hard cases refused
clearly, the Fourier term's relation to the MSE."""
import math

import pytest
import torch

from unwrap.learned.checkpoint import (FORMAT, FORMAT_VERSION, arch_from_config, build_model, export_model,
                                       load_model, read_checkpoint, save_atomic)
from unwrap.learned.config import resolve_config, to_toml
from unwrap.learned.errors import CheckpointError, ConfigError
from unwrap.learned.losses import LossWeights, composite_loss, fourier_loss, mse_loss
from unwrap.learned.network import FringeUNet


def _maps(seed=0, B=3, H=24, W=40):
    g = torch.Generator().manual_seed(seed)
    pred, target = torch.randn(B, H, W, generator=g), torch.randn(B, H, W, generator=g)
    mask = torch.rand(B, H, W, generator=g) > 0.3
    return pred, target, mask


def test_unweighted_fourier_term_is_the_mse_by_parseval_and_focal_weights_only_lower_it():
    pred, target, mask = _maps()
    mse = mse_loss(pred, target, mask)
    assert torch.allclose(fourier_loss(pred, target, mask, weighting="none"), mse, rtol=1e-5)
    for w in ("focal", "log_focal"):
        fl = fourier_loss(pred, target, mask, weighting=w, alpha=1.0)
        assert 0 < float(fl) < float(mse)


def test_losses_are_per_sample_means_so_batches_split_across_processes_agree():
    """mean over 2 halves == the whole batch (what DistributedDataParallel's gradient averaging needs),
    even though the halves have different numbers of valid pixels."""
    pred, target, mask = _maps(B=4)
    mask[0, :, :5] = False
    for fn in (mse_loss, lambda p, t, m: fourier_loss(p, t, m, weighting="focal")):
        whole = fn(pred, target, mask)
        halves = 0.5 * (fn(pred[:2], target[:2], mask[:2]) + fn(pred[2:], target[2:], mask[2:]))
        assert torch.allclose(whole, halves, rtol=1e-6)


def test_masked_pixels_do_not_change_any_loss_even_when_nan():
    pred, target, mask = _maps()
    w = LossWeights(mse=1, fourier=0.5, ce=1)
    logits = torch.randn(3, 5, 24, 40)
    t = torch.randint(-2, 3, (3, 24, 40)).float()
    a, _ = composite_loss(w, pred, t, mask, logits=logits, classes=t.long() + 2)
    pred2, logits2 = pred.clone().requires_grad_(True), logits.clone()
    with torch.no_grad():
        pred2[~mask] = float("nan")
        logits2.permute(0, 2, 3, 1)[~mask] = 1e4
    b, _ = composite_loss(w, pred2, t, mask, logits=logits2, classes=t.long() + 2)
    assert torch.allclose(a, b, rtol=1e-6)
    b.backward()
    assert torch.isfinite(pred2.grad).all() and (pred2.grad[~mask] == 0).all()


def test_a_sample_without_valid_pixels_contributes_zero_not_nan():
    pred, target, mask = _maps()
    mask[1] = False
    assert torch.isfinite(mse_loss(pred, target, mask))
    assert torch.isfinite(fourier_loss(pred, target, mask))
    mask[:] = False
    assert float(mse_loss(pred, target, mask)) == 0.0


def test_network_keeps_any_image_size_and_is_batch_independent():
    net = FringeUNet(7, 5, width=8, depth=3).eval()
    x = torch.randn(3, 7, 37, 53)
    with torch.no_grad():
        out = net(x)
        one = net(x[1:2])
    assert out.shape == (3, 5, 37, 53)
    assert torch.allclose(out[1:2], one, atol=1e-5)      # GroupNorm: no batch statistics


def _ck(tmp_path, **model_overrides):
    cfg = resolve_config(None, [f"model.{k}={v}" for k, v in model_overrides.items()] + ["data.synthetic_samples=4"])
    arch = arch_from_config(cfg.model)
    ck = {"format": FORMAT, "format_version": FORMAT_VERSION, "arch": arch, "model": build_model(arch).state_dict(),
          "meta": {"frequencies": {"mf": [1.0, 48.0]}}}
    return save_atomic(ck, tmp_path / "m.pt"), ck


def test_checkpoint_round_trip_and_export(tmp_path):
    path, ck = _ck(tmp_path, width=8, depth=2)
    model, ck2 = load_model(path)
    assert ck2["arch"] == ck["arch"]
    small = export_model(ck2, tmp_path / "small.pt")
    assert load_model(small)[1]["arch"] == ck["arch"]


def test_checkpoint_of_another_architecture_is_refused_naming_the_mismatch(tmp_path):
    path, ck = _ck(tmp_path, width=8, depth=2)
    ck["arch"] = {**ck["arch"], "width": 12}
    save_atomic(ck, tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="do not fit the architecture.*shape mismatches"):
        load_model(tmp_path / "other.pt")
    ck["arch"] = {**ck["arch"], "width": 8, "depth": 3}
    save_atomic(ck, tmp_path / "deeper.pt")
    with pytest.raises(CheckpointError, match="missing"):
        load_model(tmp_path / "deeper.pt")
    ck["arch"] = {**ck["arch"], "depth": 2, "kind": "prior_free"}
    save_atomic(ck, tmp_path / "kind.pt")
    with pytest.raises(CheckpointError, match="12 inputs"):
        load_model(tmp_path / "kind.pt")


def test_corrupt_foreign_and_diverged_checkpoints_are_refused(tmp_path):
    path, ck = _ck(tmp_path, width=8, depth=2)
    data = path.read_bytes()
    (tmp_path / "cut.pt").write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError, match="not a readable checkpoint"):
        load_model(tmp_path / "cut.pt")
    (tmp_path / "text.pt").write_text("hello")
    with pytest.raises(CheckpointError, match="not a readable checkpoint"):
        load_model(tmp_path / "text.pt")
    torch.save({"state_dict": {}}, tmp_path / "foreign.pt")
    with pytest.raises(CheckpointError, match="not an sltwin unwrapping model"):
        read_checkpoint(tmp_path / "foreign.pt")
    torch.save({**ck, "format_version": 99}, tmp_path / "future.pt")
    with pytest.raises(CheckpointError, match="version 99"):
        read_checkpoint(tmp_path / "future.pt")
    bad = {k: v.clone() for k, v in ck["model"].items()}
    next(v for v in bad.values() if v.is_floating_point()).fill_(float("nan"))
    save_atomic({**ck, "model": bad}, tmp_path / "nan.pt")
    with pytest.raises(CheckpointError, match="non-finite"):
        load_model(tmp_path / "nan.pt")
    with pytest.raises(CheckpointError, match="not found"):
        load_model(tmp_path / "absent.pt")


def test_atomic_save_leaves_the_old_file_when_the_write_fails(tmp_path):
    path, ck = _ck(tmp_path, width=8, depth=2)
    before = path.read_bytes()

    class Boom:
        def __reduce__(self):
            raise RuntimeError("disk full")
    with pytest.raises(RuntimeError):
        save_atomic({"x": Boom()}, path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_unknown_config_keys_and_bad_values_are_refused_by_name(tmp_path):
    bad = tmp_path / "c.toml"
    bad.write_text("[optim]\nlr = 1e-3\nlearning_rate = 2\n")
    with pytest.raises(ConfigError, match="unknown key 'optim.learning_rate'"):
        resolve_config(bad)
    bad.write_text("[optimiser]\nlr = 1e-3\n")
    with pytest.raises(ConfigError, match=r"unknown section \[optimiser\]"):
        resolve_config(bad)
    with pytest.raises(ConfigError, match="optim.steps = 'many'"):
        resolve_config(None, ["optim.steps=many", "data.synthetic_samples=4"])
    with pytest.raises(ConfigError, match="model.kind"):
        resolve_config(None, ["model.kind='unet'", "data.synthetic_samples=4"])
    with pytest.raises(ConfigError, match="no training data"):
        resolve_config(None, [])
    with pytest.raises(ConfigError, match="section.key=value"):
        resolve_config(None, ["lr=3"])
    bad.write_text("[optim\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        resolve_config(bad)


def test_resolved_config_round_trips_through_its_toml(tmp_path):
    cfg = resolve_config(None, ["data.synthetic_samples=6", "loss.fourier=0.5", "data.crop=[64, 64]"])
    (tmp_path / "r.toml").write_text(to_toml(cfg))
    assert resolve_config(tmp_path / "r.toml") == cfg
    assert cfg.loss.fourier == 0.5 and cfg.data.crop == (64, 64)


def test_an_infinite_grad_clip_round_trips_so_the_run_can_resume(tmp_path):
    """optim.grad_clip=inf (no clipping) was written as JSON's ``Infinity``, which TOML rejects."""
    cfg = resolve_config(None, ["data.synthetic_samples=6", "optim.grad_clip=inf"])
    (tmp_path / "r.toml").write_text(to_toml(cfg))
    back = resolve_config(tmp_path / "r.toml")
    assert back == cfg and back.optim.grad_clip == float("inf")


def test_separable_convolutions_are_an_architecture_option_the_shipped_arch_does_not_carry(tmp_path):
    """``model.conv = "separable"``: same shapes and receptive-field layout, fewer multiply-adds;
    only a non-default value enters ``arch``, so existing checkpoints keep their arch dict; a
    checkpoint of the other kind is refused for fine-tuning, naming ``conv``."""
    from unwrap.learned.network import count_macs
    from unwrap.learned.train import init_weights

    full = resolve_config(None, ["data.synthetic_samples=2", "model.width=8"])
    sep = resolve_config(None, ["data.synthetic_samples=2", "model.width=8", "model.conv=separable"])
    a_full, a_sep = arch_from_config(full.model), arch_from_config(sep.model)
    assert "conv" not in a_full and a_sep["conv"] == "separable"
    n_full, n_sep = build_model(a_full).eval(), build_model(a_sep).eval()
    x = torch.randn(1, a_full["in_channels"], 40, 56)
    with torch.inference_mode():
        assert n_sep(x).shape == n_full(x).shape == (1, a_full["out_channels"], 40, 56)
    m_full, m_sep = count_macs(n_full, a_full["in_channels"], (64, 64)), count_macs(n_sep, a_sep["in_channels"], (64, 64))
    assert 0 < m_sep < m_full / 2
    path = tmp_path / "sep.pt"
    export_model({"format": FORMAT, "format_version": FORMAT_VERSION, "arch": a_sep, "model": n_sep.state_dict(),
                  "meta": {}}, path)
    with pytest.raises(CheckpointError, match="conv"):
        init_weights(str(path), a_full)
    with pytest.raises(ConfigError, match="conv"):
        resolve_config(None, ["data.synthetic_samples=2", "model.conv=grouped"])
