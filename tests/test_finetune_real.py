"""Adapting the learned model to a scanner: ladder labels of a real-like capture, fine-tuning from a
checkpoint (--init / model.init) and the by-capture validation split (docs/learned.md, "Adapting
to your scanner")."""
import json
import math

import cv2
import h5py
import numpy as np
import pytest
import torch

from unwrap.patterns import absolute_phase, fringe_intensity

W_CAM, H_CAM, W_PRJ, STEPS = 96, 64, 1024, 8
TOML = """
[pattern]
steps = 8
frequencies = [1, 4, 16]
[projector]
size = [1024, 768]
"""


def render_ladder_capture(folder, *, seed=0, bias_f16=0.6, weak_b=10.0, noise=0.7):
    """An 8-bit MF 1/4/16 capture (v only), 96x64, with three defects in known blocks:

    - columns 40-59: the unit phase biased by ``bias_f16`` periods of f = 16 (0.6: the direct 1 -> 16
      jump is wrong there, the 1 -> 4 -> 16 ladder is right: its first step sees 0.15 period);
    - columns 60-79: biased by 1.6 periods of 16 (0.4 period at the ladder's first step: excluded);
    - rows 0-9: fringe amplitude ``weak_b`` grey levels (low modulation).
    Returns the true projector column (H, W)."""
    folder.mkdir(parents=True)
    (folder / "capture.toml").write_text(TOML)
    y, x = np.mgrid[0:H_CAM, 0:W_CAM].astype(np.float64)
    c = 20.0 + 10.2 * x + 0.5 * y
    bias = np.where((x >= 40) & (x < 60), bias_f16, 0.0) + np.where((x >= 60) & (x < 80), 1.6, 0.0)
    B = np.where(y < 10, weak_b, 90.0)
    rng = np.random.default_rng(seed)
    for f in (1, 4, 16):
        Phi = absolute_phase(c, f, W_PRJ) + (bias * 2 * math.pi / 16 if f == 1 else 0.0)
        for n in range(STEPS):
            I = fringe_intensity(Phi, n, STEPS, A=120.0, B=B) + rng.normal(0, noise, Phi.shape)
            cv2.imwrite(str(folder / f"v_f{f:03d}_n{n:02d}.png"), np.clip(np.round(I), 0, 255).astype(np.uint8))
    return c


def _export(folder, out, **kw):
    from synth.export.capture import export_capture
    return export_capture(folder, out, reference="ladder", ladder_min_modulation=0.05, **kw)


def test_ladder_labels_are_the_true_orders_where_trusted_and_name_what_they_exclude(tmp_path):
    from unwrap.dataset import FringeOrderDataset

    c = render_ladder_capture(tmp_path / "cap")
    s = _export(tmp_path / "cap", tmp_path / "cap.h5")
    stats = s["captures"][0]["orientations"]["v"]
    ex = stats["ladder_excluded"]
    assert ex["modulation"] >= 0.9 * 10 * W_CAM          # the weak rows (a few may already be flagged invalid)
    assert ex["consistency"] >= 0.9 * 20 * (H_CAM - 10)  # the block biased beyond the ladder's margin
    item = FringeOrderDataset(tmp_path / "cap.h5", method="mf", frequencies=(1, 16), orientation="v")[0]
    ref, valid = item["order_true"].numpy(), item["valid"].numpy()
    phi = item["phase_high"][0].numpy().astype(np.float64)
    true = np.rint((absolute_phase(c, 16, W_PRJ) - phi) / (2 * math.pi))
    has = valid & (ref >= 0)
    assert has.sum() > 0.6 * H_CAM * W_CAM
    assert np.array_equal(ref[has], true[has])                       # exactly the true orders
    assert not has[:10].any() and not has[10:, 60:80].any()         # excluded blocks carry no label
    trad = item["order_traditional"].numpy()
    wrong = has & (trad != ref)
    assert wrong[:, 40:60].mean() > 0.5 and not wrong[:, :40].any()   # the labels fix the 1 -> 16 jump's errors
    with h5py.File(tmp_path / "cap.h5", "r") as h5:                   # only the top frequency is labelled
        assert (h5["v/reference_order"][0, :2] == -1).all()


def test_ladder_needs_redundancy(tmp_path):
    from unwrap.errors import UnwrapError
    from unwrap.ladder_reference import check_redundant_ladder

    with pytest.raises(UnwrapError, match="three or more"):
        check_redundant_ladder([1, 16])
    assert check_redundant_ladder([1, 4, 16]).tolist() == [1, 4, 16]


def test_halves_of_one_capture_share_no_pixel(tmp_path):
    render_ladder_capture(tmp_path / "cap")
    masks = {}
    for half in ("left", "right"):
        _export(tmp_path / "cap", tmp_path / f"{half}.h5", region=half)
        with h5py.File(tmp_path / f"{half}.h5", "r") as h5:
            masks[half] = h5["masks"][0] != 0
            ref = h5["v/reference_order"][0, -1]
        assert masks[half].any()
        assert ((ref >= 0) <= masks[half]).all()
    assert not (masks["left"] & masks["right"]).any()


def test_by_capture_split_never_mixes_captures(tmp_path):
    from unwrap.learned.config import resolve_config
    from unwrap.learned.data import build_datasets
    from unwrap.learned.errors import ConfigError

    files = []
    for i in range(3):
        render_ladder_capture(tmp_path / f"cap{i}", seed=i)
        files.append(str(tmp_path / f"cap{i}.h5"))
        _export(tmp_path / f"cap{i}", files[-1])
    base = ["data.methods=[\"mf\"]", "data.mf_frequencies=[1.0, 16.0]", "data.orientations=[\"v\", \"h\"]",
            "data.crop=[32, 32]"]
    cfg = resolve_config(None, base + [f"data.train={json.dumps(files[:2])}",
                                       f"data.val_files={json.dumps(files[2:])}"])
    train, val, info = build_datasets(cfg)
    tr = {str(p) for d in train.datasets for p in d.ds.paths}
    va = {str(p) for d in val.datasets for p in d.ds.paths}
    assert tr == set(files[:2]) and va == {files[2]} and not tr & va
    assert len(train) == 2 and len(val) == 1                   # v only: the files hold no h
    assert info["split"] == "by file (capture)"
    with pytest.raises(ConfigError, match="cap0.h5"):
        resolve_config(None, base + [f"data.train={json.dumps(files[:2])}", f"data.val_files={json.dumps(files[:1])}"])


def _tiny_cfg():
    return ["data.synthetic_samples=4", "data.synthetic_size=[64, 64]", "data.methods=[\"mf\"]",
            "data.orientations=[\"v\"]", "data.val_fraction=0.0", "optim.batch_size=2", "optim.steps=2",
            "run.threads=1", "run.val_every=1000"]


def _first_batch_loss(cfg, model):
    from unwrap.learned.data import ResumableSampler, build_datasets
    from unwrap.learned.distributed import seed_everything
    from unwrap.learned.train import training_step_loss

    seed_everything(cfg.run.seed)
    train, _, _ = build_datasets(cfg)
    sampler = ResumableSampler(len(train), seed=cfg.run.seed)
    batch = next(iter(torch.utils.data.DataLoader(train, batch_size=2, sampler=sampler, drop_last=True)))
    with torch.no_grad():
        loss, _ = training_step_loss(model.train(), batch, cfg, cfg.loss)
    return float(loss)


def test_init_starts_from_the_checkpoint_and_keeps_training(tmp_path):
    from unwrap.learned.checkpoint import load_model
    from unwrap.learned.config import FINETUNE_LR, resolve_config
    from unwrap.learned.infer import shipped_model_path
    from unwrap.learned.train import train

    cfg = resolve_config(None, _tiny_cfg() + ["model.init=learned"])
    assert cfg.optim.lr == FINETUNE_LR
    assert resolve_config(None, _tiny_cfg() + ["model.init=learned", "optim.lr=1e-3"]).optim.lr == 1e-3
    init, _ = load_model(shipped_model_path())
    expected = _first_batch_loss(cfg, init)
    losses = []
    r = train(None, _tiny_cfg() + ["model.init=learned"], tmp_path / "ft", progress=False,
              on_step=lambda step, loss: losses.append(loss))
    assert losses[0] == pytest.approx(expected, rel=1e-4, abs=1e-7)
    fresh = []
    train(None, _tiny_cfg(), tmp_path / "fresh", progress=False, on_step=lambda step, loss: fresh.append(loss))
    assert abs(fresh[0] - expected) > 1e-3 * max(abs(expected), 1e-3)   # the init changed the start
    tuned, _ = load_model(tmp_path / "ft" / "model.pt")
    # the learned weights (a BatchNorm model's running statistics are buffers that follow the new data)
    a, b = dict(init.named_parameters()), dict(tuned.named_parameters())
    assert r.step == 2
    assert any(not torch.equal(a[k], b[k]) for k in a)                    # training moved the weights
    assert max(float((a[k] - b[k]).abs().max()) for k in a) < 0.05


def test_init_refuses_another_kind_or_architecture(tmp_path):
    from unwrap.learned.errors import CheckpointError
    from unwrap.learned.train import train

    with pytest.raises(CheckpointError, match="prior_free"):
        train(None, _tiny_cfg() + ["model.init=learned", "model.kind=prior_free"], tmp_path / "a", progress=False)
    from unwrap.learned.checkpoint import read_checkpoint
    from unwrap.learned.infer import shipped_model_path

    w = read_checkpoint(shipped_model_path())["arch"]["width"]
    other = 16 if w != 16 else 8
    with pytest.raises(CheckpointError, match=f"width: checkpoint {w}, run {other}"):
        train(None, _tiny_cfg() + ["model.init=learned", f"model.width={other}"], tmp_path / "b", progress=False)
