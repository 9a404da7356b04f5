"""Using a trained model: frequency-range checks, the learned capture path (`calib unwrap
--model`), `calib eval` and `calib train` on the command line, with small hand-set models."""
import json
import warnings

import numpy as np
import pytest
import torch

from sltwin.cli import main
from unwrap.learned.checkpoint import FORMAT, FORMAT_VERSION, arch_from_config, build_model, save_atomic
from unwrap.learned.config import resolve_config
from unwrap.learned.errors import FrequencyRangeWarning, ModelError
from unwrap.learned.infer import check_frequency_range, unwrap_learned
from unwrap.learned.synthetic import synthetic_sample
from unwrap.patterns import absolute_phase

META = {"frequencies": {"mf": [1.0, 48.0], "mw": [47.0, 48.0], "nt": [47.0, 48.0]}}


def constant_model(path, correction: int = 0, kind: str = "physics"):
    """A checkpoint whose network outputs one correction class everywhere (confidence ~1)."""
    cfg = resolve_config(None, ["data.synthetic_samples=4", "model.width=4", "model.depth=1", f"model.kind='{kind}'"])
    arch = arch_from_config(cfg.model)
    net = build_model(arch)
    last = net.refine[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()
        if kind == "physics":
            last.bias[correction + arch["max_correction"]] = 20.0
    save_atomic({"format": FORMAT, "format_version": FORMAT_VERSION, "arch": arch, "model": net.state_dict(),
                 "meta": META}, path)
    return path


def test_frequencies_far_outside_training_are_refused_and_the_edge_of_the_range_warned():
    assert check_frequency_range(META, "mf", (1, 96))["status"] == "ok"            # table S5's unseen f
    assert check_frequency_range(META, "mf", (1, 16))["status"] == "ok"
    with pytest.warns(FrequencyRangeWarning, match="outside the tested range"):
        assert check_frequency_range(META, "mf", (1, 150))["status"] == "warn"
    with pytest.raises(ModelError, match=r"frequency ratio 400 is 8.33x the trained 48"):
        check_frequency_range(META, "mf", (1, 400))
    with pytest.raises(ModelError, match="ratio 4 is 0.08x"):
        check_frequency_range(META, "mf", (1, 4))
    with pytest.raises(ModelError, match="not trained for method 'gray'"):
        check_frequency_range(META, "gray", (1, 48))
    # a high phase that wraps every 2 camera pixels is aliased, whatever the ratio
    x = np.arange(64.0)[None, :].repeat(32, 0)
    phi = np.angle(np.exp(1j * np.pi * x))
    with pytest.raises(ModelError, match="fringe period on the camera 2.00 px"):
        check_frequency_range(META, "mf", (1, 48), phi, np.ones_like(phi, bool))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert check_frequency_range(META, "mf", (1, 400), on_outside="ignore")["status"] == "refused"


@pytest.mark.parametrize("correction", [0, 1])
def test_learned_orders_are_the_traditional_ones_plus_the_chosen_correction(tmp_path, correction):
    path = constant_model(tmp_path / "c.pt", correction)
    s = synthetic_sample(0, size=(48, 64), method="mf", frequencies=(1, 48))
    r = unwrap_learned("mf", s["phase_low"], s["phase_high"], s["modulation_low"], s["modulation_high"], s["valid"],
                       (1, 48), width=912, model=path)
    v = r.valid
    assert np.array_equal(r.order[v], np.clip(s["order_traditional"][v] + correction, 0, 48))
    assert (r.order[~v] == -1).all() and (r.confidence[~v] == 0).all()
    assert (r.confidence[v] > 0.99).all() and r.frequency_check["status"] == "ok"
    phi = s["phase_low"].copy()
    phi[3, 4] = np.nan                                                      # NaN input: invalid, not an error
    r2 = unwrap_learned("mf", phi, s["phase_high"], s["modulation_low"], s["modulation_high"], s["valid"], (1, 48),
                        width=912, model=path)
    assert r2.order[3, 4] == -1 and np.isfinite(r2.confidence).all()


def test_calib_unwrap_with_a_model_writes_the_same_hdf5_plus_confidence(design_capture, tmp_path, capsys):
    """The capture has 1, 8, 48 periods; the model takes the pair (1, 48)."""
    import h5py
    root, coords = design_capture
    model = constant_model(tmp_path / "zero.pt", 0)
    assert main(["unwrap", str(root), "--method", "mf", "-o", str(tmp_path / "trad"), "--no-previews"]) == 0
    assert main(["unwrap", str(root), "--method", "mf", "--model", str(model), "-o", str(tmp_path / "net")]) == 0
    with h5py.File(tmp_path / "trad" / "unwrap.h5") as a, h5py.File(tmp_path / "net" / "unwrap.h5") as b:
        for o, (c, extent) in coords.items():
            assert set(a[o]) <= set(b[o]) and {"confidence", "order_traditional"} <= set(b[o])
            assert np.array_equal(a[o]["order"][()], b[o]["order"][()])
            assert np.abs(b[o]["phase"][()] - absolute_phase(c, 48, extent)).max() < 2e-3
            assert b[o]["confidence"].dtype == np.float32 and (b[o]["confidence"][()] > 0.99).all()
            assert b[o].attrs["method"] == "mf+learned"
    assert "learned: 0 orders differ" in capsys.readouterr().out
    assert main(["unwrap", str(root), "--method", "gray", "--model", str(model), "-o", str(tmp_path / "x")]) == 2
    assert main(["unwrap", str(root), "--model", str(tmp_path / "missing.pt"), "-o", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "--model works with --method mf" in err and "checkpoint not found" in err


def test_calib_eval_writes_the_s5_and_s6_layouts_with_the_paper_numbers(tmp_path, capsys):
    physics = constant_model(tmp_path / "p.pt", 0)
    prior_free = constant_model(tmp_path / "pf.pt", kind="prior_free")
    out = tmp_path / "eval"
    assert main(["eval", "--model", str(physics), "--prior-free", str(prior_free), "--mse-only", str(physics),
                 "--synthetic", "1", "--s5", "48", "96", "--s6", "48", "--no-speed", "-o", str(out)]) == 0
    md = (out / "eval.md").read_text()
    assert "| 48 (seen) | Traditional |" in md and "| 96 (unseen) | DP-TPU (physics-aware) |" in md
    assert "3.39" in md and "11.40" in md and "0.68 / 0.66" in md          # paper S5 / S6 beside ours
    res = json.loads((out / "eval.json").read_text())
    s5 = res["s5"]["48"]
    # a zero-correction model is the traditional method: same error rate, same pixels
    for m in ("mf", "mw", "nt"):
        assert s5["DP-TPU (physics-aware)"][m]["ours"] == s5["Traditional"][m]["ours"]
        assert s5["DT-TPU (prior-free)"][m]["ours"] > 0.9                   # predicts order 0 everywhere
    assert (out / "confidence.png").is_file() and (out / "s6.png").is_file() and (out / "error_maps_mf48.png").is_file()
    assert main(["eval", "--model", str(physics), "-o", str(out)]) == 2
    assert "either --test" in capsys.readouterr().err


def test_speed_table_times_every_path(tmp_path):
    from experiments.learned_evaluation import speed_table
    sp = speed_table(constant_model(tmp_path / "p.pt", 0), size=(48, 64), repeats=1)
    assert sp["size"] == "64x48" and sp["device"] == "cpu"
    for k in ("traditional_from_phases_ms", "traditional_from_frames_ms", "filtered_ms", "network_forward_ms",
              "learned_total_ms"):
        assert np.isfinite(sp[k]), k
    # the paths timed compute the same fringe orders on the table's scene (not only that they ran)
    assert sp["valid_pixels"] > 0.9 * 48 * 64
    assert sp["orders_frames_vs_phases"] > 0.999 and sp["orders_learned_traditional_vs_phases"] > 0.999


def test_calib_train_command_line_runs_resumes_and_refuses_typos(tmp_path, capsys):
    args = ["train", "data.synthetic_samples=4", "data.synthetic_size=[32, 32]", "data.crop=[]",
            "data.orientations=['v']", "data.methods=['mf']", "model.width=4", "model.depth=1", "optim.batch_size=2",
            "optim.steps=2", "run.val_every=2", "run.device=cpu", "-q"]
    assert main(args + ["-o", str(tmp_path / "r")]) == 0
    assert main(["train", "--resume", str(tmp_path / "r"), "optim.steps=3", "-q"]) == 0
    assert "step 3" in capsys.readouterr().out
    assert main(["train", "optim.setps=2", "data.synthetic_samples=4", "-o", str(tmp_path / "s")]) == 2
    assert "unknown key 'optim.setps'" in capsys.readouterr().err


def test_the_learned_capture_path_refuses_what_the_traditional_path_refuses(design_capture, tmp_path, capsys):
    """Issue 15's checks hold with --model too: frames written with a pi offset (another lab's
    convention) are refused by the prior check unless --no-prior-check, and a frame of another bit
    depth is refused by name."""
    import shutil

    import cv2
    root, _ = design_capture
    model = str(constant_model(tmp_path / "zero.pt", 0))
    offset = tmp_path / "offset"
    shutil.copytree(root, offset)
    for png in (offset / "pose_00").glob("*.png"):        # A + B cos(Phi + pi - delta) = 2A - I
        cv2.imwrite(str(png), (60000 - cv2.imread(str(png), -1).astype(np.int64)).astype(np.uint16))
    assert main(["unwrap", str(offset), "--model", model, "-o", str(tmp_path / "a"), "--no-previews"]) == 2
    assert "half integers" in capsys.readouterr().err
    assert main(["unwrap", str(offset), "--model", model, "--no-prior-check", "-o", str(tmp_path / "b"),
                 "--no-previews"]) == 0
    mixed = tmp_path / "mixed"
    shutil.copytree(root, mixed)
    frame = mixed / "pose_00" / "v_f048_n03.png"
    cv2.imwrite(str(frame), (cv2.imread(str(frame), -1) // 257).astype(np.uint8))
    capsys.readouterr()
    assert main(["unwrap", str(mixed), "--model", model, "-o", str(tmp_path / "c"), "--no-previews"]) == 2
    assert "v_f048_n03.png: uint8 frame among uint16 frames" in capsys.readouterr().err
