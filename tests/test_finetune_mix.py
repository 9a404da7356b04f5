"""Fine-tuning on a mix (docs/learned.md, "Retraining on thin-lens real-like scenes"): files split
by scene as a from-scratch run splits them (``data.split_files``) beside whole training and
validation files, and the best step picked by the geometric mean of the per-file validation error
rates (``run.val_score = "groups"``)."""
import csv
import json
import math

import numpy as np
import pytest

from test_finetune_real import _export, render_ladder_capture

BASE = ["data.methods=[\"mf\"]", "data.mf_frequencies=[1.0, 16.0]", "data.orientations=[\"v\"]",
        "data.crop=[32, 32]"]


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    root = tmp_path_factory.mktemp("mix")
    files = []
    for i in range(4):
        render_ladder_capture(root / f"cap{i}", seed=i, bias_f16=0.6 + 0.1 * i)
        files.append(str(root / f"cap{i}.h5"))
        _export(root / f"cap{i}", files[-1])
    return files


def test_split_files_hold_out_the_from_scratch_runs_scenes(captures):
    from unwrap.learned.config import resolve_config
    from unwrap.learned.data import build_datasets, split_scenes
    from unwrap.learned.errors import ConfigError

    split, tr_file, va_file = captures[:2], captures[2], captures[3]
    cfg = resolve_config(None, BASE + [f"data.split_files={json.dumps(split)}", f"data.train={json.dumps([tr_file])}",
                                       f"data.val_files={json.dumps([va_file])}", "data.val_fraction=0.5",
                                       "data.val_samples=1", "run.seed=3"])
    train, val, info = build_datasets(cfg)
    want_tr, want_va = split_scenes(2, 0.5, 1, 3)        # what a from-scratch run on the two files holds out
    s_tr = [d for d in train.datasets if list(map(str, d.ds.paths)) == split]
    s_va = [d for d in val.datasets if getattr(d, "group", None) == "split"]
    assert len(s_tr) == 1 and len(s_va) == 1
    assert s_tr[0].ds.samples.tolist() == want_tr.tolist() and s_va[0].ds.samples.tolist() == want_va.tolist()
    assert not set(s_tr[0].ds.samples.tolist()) & set(s_va[0].ds.samples.tolist())
    assert {getattr(d, "group", None) for d in val.datasets} == {"split", "cap3.h5"}
    assert info["val_scenes"] == [va_file, f"split:{int(want_va[0])}"]
    assert len(train) == 2 and len(val) == 2               # one scene of the split + the training file; v only
    with pytest.raises(ConfigError, match="val_files as well"):
        resolve_config(None, BASE + [f"data.split_files={json.dumps(split)}", f"data.train={json.dumps([tr_file])}"])
    with pytest.raises(ConfigError, match="cap2.h5"):
        resolve_config(None, BASE + [f"data.split_files={json.dumps(captures[1:3])}", f"data.train={json.dumps([tr_file])}",
                                     f"data.val_files={json.dumps([va_file])}"])


def test_best_step_by_the_groups_geometric_mean(captures, tmp_path):
    from unwrap.learned.config import resolve_config
    from unwrap.learned.errors import ConfigError
    from unwrap.learned.train import train

    ov = BASE + [f"data.split_files={json.dumps(captures[:2])}", f"data.train={json.dumps([captures[2]])}",
                 f"data.val_files={json.dumps([captures[3]])}", "data.val_fraction=0.5", "data.val_samples=1",
                 "model.width=4", "model.max_width=8", "optim.batch_size=2", "optim.steps=2", "run.val_every=1",
                 "run.threads=1", "run.val_score=groups"]
    res = train(None, ov, tmp_path / "run", progress=False)
    with open(tmp_path / "run" / "val_groups.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    with open(tmp_path / "run" / "val.csv", newline="") as fh:
        pooled = list(csv.DictReader(fh))
    assert [r["step"] for r in rows] == ["1", "1", "2", "2"] and {r["group"] for r in rows} == {"split", "cap3.h5"}
    scores = {}
    for step in ("1", "2"):
        g = [r for r in rows if r["step"] == step]
        rates = [float(r["error_model"]) for r in g]
        floors = [0.5 / int(r["pixels"]) for r in g]                                  # half a pixel per group
        scores[step] = math.exp(np.mean(np.log(np.maximum(rates, floors))))
        wrong = sum(round(float(r["error_model"]) * int(r["pixels"])) for r in g)     # the pooled rate is their sum
        p = next(r for r in pooled if r["step"] == step)
        assert int(p["pixels"]) == sum(int(r["pixels"]) for r in g)
        assert wrong == pytest.approx(float(p["error_model"]) * int(p["pixels"]), abs=0.5)
    assert res.best_error == pytest.approx(min(scores.values()), rel=1e-9)
    with pytest.raises(ConfigError, match="val_score"):
        resolve_config(None, ["run.val_score=mean"])
    with pytest.raises(ConfigError, match="val_files"):                               # one group: nothing to weigh
        resolve_config(None, BASE + [f"data.train={json.dumps(captures[:2])}", "run.val_score=groups"])


def test_group_score_floors_an_error_free_group_at_half_a_pixel():
    """A group with no wrong pixel counts as half a wrong pixel (the count's resolution), not as a
    rate of 1e-9: that floor made 0 / 3 % / 3 % (1,000 pixels each) score 0.0097 %, 50x better than
    0.5 % in every group; with the floor it scores 0.77 %."""
    from unwrap.learned.metrics import ErrorCount
    from unwrap.learned.train import group_score

    zero = group_score([ErrorCount(0, 1000), ErrorCount(30, 1000), ErrorCount(30, 1000)])
    even = group_score([ErrorCount(5, 1000), ErrorCount(5, 1000), ErrorCount(5, 1000)])
    assert zero == pytest.approx((0.0005 * 0.03 * 0.03) ** (1 / 3), rel=1e-12)
    assert even == pytest.approx(0.005, rel=1e-12) and even < zero
    assert group_score([ErrorCount(2, 100), ErrorCount(0, 0)]) == pytest.approx(0.02, rel=1e-12)  # empty: left out
    assert math.isnan(group_score([ErrorCount(0, 0)]))


def test_a_killed_run_resumes_its_group_rows_and_best_score(captures, tmp_path):
    """Killed after step 3's validation (last checkpoint: step 2), resumed to step 4: val_groups.csv
    holds each (step, group) once, and the best score is the least over all four steps."""
    from unwrap.learned.checkpoint import read_checkpoint
    from unwrap.learned.train import train

    ov = BASE + [f"data.split_files={json.dumps(captures[:2])}", f"data.train={json.dumps([captures[2]])}",
                 f"data.val_files={json.dumps([captures[3]])}", "data.val_fraction=0.5", "data.val_samples=1",
                 "model.width=4", "model.max_width=8", "optim.batch_size=2", "optim.steps=4", "run.val_every=1",
                 "run.checkpoint_every=2", "run.threads=1", "run.val_score=groups"]

    def kill(step, loss):
        if step == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(None, ov, tmp_path / "run", progress=False, on_step=kill)
    with open(tmp_path / "run" / "val_groups.csv", newline="") as fh:
        assert max(int(r["step"]) for r in csv.DictReader(fh)) == 3          # logged after the last checkpoint
    assert read_checkpoint(tmp_path / "run" / "last.pt")["step"] == 2
    res = train(resume=tmp_path / "run", progress=False)
    assert res.step == 4
    with open(tmp_path / "run" / "val_groups.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert sorted((int(r["step"]), r["group"]) for r in rows) == sorted(
        (s, g) for s in (1, 2, 3, 4) for g in ("split", "cap3.h5"))
    scores = []
    for step in ("1", "2", "3", "4"):
        g = [r for r in rows if r["step"] == step]
        floors = [0.5 / int(r["pixels"]) for r in g]
        scores.append(math.exp(np.mean(np.log(np.maximum([float(r["error_model"]) for r in g], floors)))))
    assert res.best_error == pytest.approx(min(scores), rel=1e-9)
