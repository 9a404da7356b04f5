"""The lighter network options (``[model] norm``, ``[model] stem``; docs/speed.md "A lighter
network"): what each claims to be, checked - the strided stem is the shuffle stem's function, a
network without frame-wide normalisation depends only on its receptive field, BatchNorm folds away
in the exported ONNX graph and gives torch's logits, and the shipped architecture is unchanged."""
import numpy as np
import pytest
import torch

from unwrap.learned.checkpoint import arch_from_config, build_model
from unwrap.learned.config import resolve_config
from unwrap.learned.errors import ConfigError
from unwrap.learned.network import FringeUNet, count_macs

LIGHT = ["model.width=8", "model.norm=batch", "model.stem=strided"]


def _arch(overrides=()):
    return arch_from_config(resolve_config(None, ["data.synthetic_samples=2", *overrides]).model)


def _light_checkpoint(tmp_path):
    """(arch, path) of an untrained LIGHT model's checkpoint."""
    from unwrap.learned.checkpoint import FORMAT, FORMAT_VERSION, export_model

    arch = _arch(LIGHT)
    return arch, export_model({"format": FORMAT, "format_version": FORMAT_VERSION, "arch": arch,
                               "model": build_model(arch).state_dict(), "meta": {}}, tmp_path / "light.pt")


def test_only_non_default_options_enter_the_arch_and_bad_values_are_refused():
    shipped = _arch()
    assert "norm" not in shipped and "stem" not in shipped     # existing checkpoints keep their arch dict
    light = _arch(LIGHT)
    assert light["norm"] == "batch" and light["stem"] == "strided" and light["width"] == 8
    for bad in ("model.norm=layer", "model.stem=pooled"):
        with pytest.raises(ConfigError, match=bad.split("=")[0]):
            resolve_config(None, ["data.synthetic_samples=2", bad])
    with pytest.raises(ValueError, match="stem"):
        FringeUNet(7, 5, stem="pooled")


def test_strided_stem_is_the_pixel_shuffle_stem_with_its_weights_rearranged():
    """unshuffle + 3x3 conv == one 6x6 stride-2 conv; 1x1 head + pixel-shuffle + 1x1 refine of
    the concatenation == 2x2 stride-2 transposed conv + 1x1 conv of the raw inputs (with a head
    bias that is the same for the 4 sub-pixels of a channel)."""
    torch.manual_seed(0)
    C, K, w = 7, 5, 8
    a = FringeUNet(C, K, width=w, depth=2, norm="none", stem="shuffle").eval()
    b = FringeUNet(C, K, width=w, depth=2, norm="none", stem="strided").eval()
    with torch.no_grad():
        a.head.bias.copy_(torch.randn(w).repeat_interleave(4))
        sa, sb = a.state_dict(), b.state_dict()
        for k in sb:
            if k in sa and sa[k].shape == sb[k].shape:
                sb[k] = sa[k].clone()
        w3 = sa["enc.0.0.weight"]                              # (c0, 4C, 3, 3), channel c*4 + i*2 + j
        w6 = torch.zeros_like(sb["enc.0.0.weight"])            # (c0, C, 6, 6)
        for c in range(C):
            for i in range(2):
                for j in range(2):
                    w6[:, c, i::2, j::2] = w3[:, c * 4 + i * 2 + j]
        sb["enc.0.0.weight"] = w6
        sb["enc.0.0.bias"] = sa["enc.0.0.bias"].clone()
        r0 = sa["refine.0.weight"][:, :, 0, 0]                 # (w, C + w): raw inputs, then shuffled head
        sb["raw.weight"] = r0[:, :C, None, None].clone()
        mix = r0[:, C:]                                       # refine's weights on the w shuffled channels
        head = sa["head.weight"][:, :, 0, 0].reshape(w, 4, -1)  # (c, i*2 + j, c0)
        sb["head.weight"] = torch.einsum("oc,csm->mos", mix, head).reshape(-1, w, 2, 2)
        sb["head.bias"] = mix @ sa["head.bias"].reshape(w, 4)[:, 0] + sa["refine.0.bias"]
        sb["refine.1.weight"], sb["refine.1.bias"] = sa["refine.2.weight"].clone(), sa["refine.2.bias"].clone()
        b.load_state_dict(sb)
        x = torch.randn(2, C, 40, 56)
        ya, yb = a(x), b(x)
    assert ya.shape == yb.shape == (2, K, 40, 56)
    assert float((ya - yb).abs().max()) < 1e-4 * float(ya.abs().max())
    assert count_macs(b, C, (64, 64)) < count_macs(a, C, (64, 64))


@pytest.mark.parametrize("norm, local", [("batch", True), ("none", True), ("group", False)])
def test_output_depends_on_the_whole_frame_only_with_group_norm(norm, local):
    """A change far outside a pixel's receptive field leaves it alone unless a frame-wide
    normalisation carries it there (why GroupNorm prevents exact tiling)."""
    torch.manual_seed(1)
    net = FringeUNet(7, 5, width=8, depth=2, norm=norm, stem="strided").eval()
    x = torch.randn(1, 7, 32, 512)
    x2 = x.clone()
    x2[..., 448:] += 3.0
    with torch.inference_mode():
        near = (net(x) - net(x2))[..., :64].abs().max()
    assert (float(near) == 0.0) == local, float(near)


def test_batchnorm_model_exports_to_onnx_with_the_torch_logits(tmp_path):
    """norm = batch: the running statistics fold into the convolutions (no normalisation node
    left after onnxruntime's optimisation) and the logits equal torch's in eval mode."""
    import onnx
    import onnxruntime as ort

    from unwrap.learned.runtime import OnnxPredictor, export_onnx

    arch = _arch(LIGHT)
    net = build_model(arch)
    g = torch.Generator().manual_seed(2)
    with torch.no_grad():
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.copy_(torch.randn(m.num_features, generator=g) * 0.2)
                m.running_var.copy_(torch.rand(m.num_features, generator=g) + 0.5)
                m.weight.copy_(torch.rand(m.num_features, generator=g) + 0.5)
    net.eval()
    path = export_onnx((net, {"arch": arch, "meta": {}}), tmp_path / "light.onnx")
    opts = ort.SessionOptions()
    opts.optimized_model_filepath = str(tmp_path / "opt.onnx")
    ort.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])
    ops = {n.op_type for n in onnx.load(str(tmp_path / "opt.onnx")).graph.node}
    assert "Conv" in ops and not ops & {"BatchNormalization", "InstanceNormalization", "GroupNormalization"}, ops
    x = np.random.default_rng(3).standard_normal((1, arch["in_channels"], 50, 70)).astype(np.float32)
    got = OnnxPredictor(path).logits(x)
    with torch.inference_mode():
        want = net(torch.from_numpy(x)).numpy()
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-4 * np.abs(want).max())


def test_a_batchnorm_strided_model_trains_and_its_checkpoint_round_trips(tmp_path):
    """A few steps on synthetic scenes: finite losses, the running statistics move and are kept
    in the checkpoint, and the model loads back with its arch."""
    from unwrap.learned.checkpoint import load_model
    from unwrap.learned.train import train

    overrides = ["data.synthetic_samples=6", "data.synthetic_size=[48, 64]", "data.crop=[32, 32]", "optim.steps=4",
                 "optim.batch_size=2", "optim.warmup_steps=1", "run.val_every=4", "run.threads=1", "model.depth=2",
                 *LIGHT]
    train(None, overrides, tmp_path / "run", progress=False)
    net, ck = load_model(tmp_path / "run" / "model.pt")
    assert ck["arch"]["norm"] == "batch" and ck["arch"]["stem"] == "strided"
    bn = [m for m in net.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    assert bn and any(float(m.running_var.sub(1).abs().max()) > 1e-3 for m in bn)
    assert int(bn[0].num_batches_tracked) == 4
    x = torch.zeros(1, ck["arch"]["in_channels"], 32, 32)
    with torch.inference_mode():
        assert torch.isfinite(net(x)).all()


def test_fine_tuning_takes_the_architecture_of_the_checkpoint_it_starts_from(tmp_path):
    """model.init set, [model] silent on the architecture: the run builds the checkpoint's network
    (so ``--init learned`` fine-tunes whatever model ships); a key that is given wins, and a
    differing one is refused when the weights are loaded."""
    from unwrap.learned.errors import CheckpointError
    from unwrap.learned.train import init_weights

    arch, path = _light_checkpoint(tmp_path)
    cfg = resolve_config(None, ["data.synthetic_samples=2", f"model.init={path}"])
    assert arch_from_config(cfg.model) == arch
    assert set(init_weights(str(path), arch_from_config(cfg.model))) == set(build_model(arch).state_dict())
    given = resolve_config(None, ["data.synthetic_samples=2", f"model.init={path}", "model.norm=group"])
    assert given.model.norm == "group" and given.model.width == 8
    with pytest.raises(CheckpointError, match=r"model.init .*\(norm: checkpoint batch, run group\)"):
        init_weights(str(path), arch_from_config(given.model))


@pytest.mark.parametrize("kernel, stride", [(2, 2), (3, 2), (4, 2), (3, 1)])
def test_count_macs_of_a_transposed_convolution_is_its_scatter_count(kernel, stride):
    """A transposed convolution does in_channels x out_channels x kernel taps per input pixel
    (the 2x2 stride-2 head of the strided stem: exactly the 1x1 head + pixel-shuffle it replaces)."""
    c_in, c_out, h, w = 6, 5, 7, 9
    net = torch.nn.ConvTranspose2d(c_in, c_out, kernel, stride=stride)
    assert count_macs(net, c_in, (h, w)) == h * w * c_in * c_out * kernel ** 2
    if kernel == stride == 2:
        assert count_macs(net, c_in, (h, w)) == count_macs(torch.nn.Conv2d(c_in, 4 * c_out, 1), c_in, (h, w))


def test_a_saved_fine_tuning_config_resolves_without_its_init_checkpoint(tmp_path):
    """A run folder's config.toml names every architecture key: reading it back (``--resume``)
    needs no init checkpoint, which may have moved since the run began."""
    from unwrap.learned.config import to_toml

    arch, path = _light_checkpoint(tmp_path)
    cfg = resolve_config(None, ["data.synthetic_samples=2", f"model.init={path}"])
    (tmp_path / "config.toml").write_text(to_toml(cfg))
    path.unlink()
    assert resolve_config(tmp_path / "config.toml") == cfg


def test_count_macs_leaves_a_training_batchnorm_model_as_it_was():
    """Counting runs one forward of zeros: a network in training mode keeps its BatchNorm running
    statistics (and its mode)."""
    net = FringeUNet(7, 5, width=8, depth=2, norm="batch", stem="strided")
    before = {k: v.clone() for k, v in net.state_dict().items()}
    assert count_macs(net, 7, (32, 32)) > 0
    assert net.training
    assert all(torch.equal(before[k], v) for k, v in net.state_dict().items())


@pytest.mark.parametrize("options", [(), ("model.conv=separable",), ("model.width=8", "model.norm=none", "model.stem=strided")])
def test_the_memory_plan_counts_the_parameters_of_the_model_as_built(options):
    from unwrap.learned.memory import _parameters
    from unwrap.learned.network import count_parameters

    arch = arch_from_config(resolve_config(None, [*options, "data.synthetic_samples=1"]).model)
    assert _parameters(arch) == count_parameters(build_model(arch))
