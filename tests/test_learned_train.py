"""The training module: run folder, resume after a kill equals an uninterrupted run, refusals,
and distributed data parallel (2 CPU processes x batch b == 1 process x batch 2b)."""
import csv
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from unwrap.learned.checkpoint import load_model, read_checkpoint
from unwrap.learned.errors import ConfigError, DatasetTooSmallError
from unwrap.learned.train import train

REPO = Path(__file__).resolve().parents[1]
TINY = ["data.synthetic_samples=6", "data.synthetic_size=[32, 48]", "data.crop=[]", "data.orientations=['v']",
        "data.methods=['mf', 'nt']", "data.val_fraction=0.2", "model.width=4", "model.depth=1", "model.max_width=8",
        "optim.batch_size=2", "optim.steps=6", "optim.warmup_steps=1", "run.val_every=3", "run.checkpoint_every=2",
        "run.log_every=1", "run.threads=1", "run.device=cpu"]
"""``run.device=cpu``: a runner with a GPU must not change what these CPU tests mean (AMP, NCCL)."""


def _weights(path):
    return read_checkpoint(path)["model"]


def _same(a, b, rtol=1e-5, atol=1e-7):
    return set(a) == set(b) and all(torch.allclose(a[k].float(), b[k].float(), rtol=rtol, atol=atol) for k in a)


def test_tiny_training_run_writes_everything_a_user_expects(tmp_path):
    run = tmp_path / "run"
    r = train(None, TINY, run, progress=False)
    assert r.step == 6
    for name in ("config.toml", "last.pt", "best.pt", "model.pt", "train.csv", "val.csv", "metrics.json",
                 "metrics.png", "log.txt"):
        assert (run / name).is_file(), name
    rows = list(csv.DictReader(open(run / "train.csv")))
    assert [int(r["step"]) for r in rows] == [1, 2, 3, 4, 5, 6]
    assert all(float(r["loss"]) > 0 for r in rows) and float(rows[-1]["samples_per_s"]) > 0
    val = list(csv.DictReader(open(run / "val.csv")))
    assert [int(r["step"]) for r in val] == [3, 6] and all(0 <= float(r["error_model"]) <= 1 for r in val)
    summary = json.loads((run / "metrics.json").read_text())
    assert summary["step"] == 6 and summary["train_samples_per_s"] > 0 and summary["val_scenes"]
    model, ck = load_model(run / "model.pt")
    assert "optimizer" not in ck and ck["meta"]["frequencies"]["mf"] == [1.0, 48.0]
    assert (run / "model.pt").stat().st_size < (run / "last.pt").stat().st_size
    assert "steps = 6" in (run / "config.toml").read_text()
    with pytest.raises(ConfigError, match="already holds a run"):
        train(None, TINY, run, progress=False)


def test_training_reduces_the_loss_on_a_fixed_batch(tmp_path):
    """Not a quality claim - a check that gradients flow: 2 scenes, one batch, 60 steps lower the loss."""
    over = TINY + ["data.synthetic_samples=2", "data.val_fraction=0", "data.methods=['mf']", "data.flip=false",
                   "optim.lr=5e-3", "run.checkpoint_every=100", "optim.warmup_steps=1"]
    r = train(None, over + ["optim.steps=60"], tmp_path / "fit", progress=False)
    rows = list(csv.DictReader(open(tmp_path / "fit" / "train.csv")))
    first, last = float(rows[0]["loss"]), sum(float(r["loss"]) for r in rows[-5:]) / 5
    assert r.step == 60 and last < 0.7 * first, (first, last)


KILL_SCRIPT = """
import os, signal, sys
sys.path.insert(0, {repo!r})
from unwrap.learned.train import train

def kill_at(step, loss):
    if step == {kill}:
        os.kill(os.getpid(), signal.SIGKILL)      # no cleanup, no final writes

train(None, {overrides!r}, {out!r}, progress=False, deterministic=True, on_step=kill_at)
"""


def test_killed_and_resumed_run_equals_an_uninterrupted_one(tmp_path):
    over = TINY + ["optim.steps=8", "run.checkpoint_every=2", "data.synthetic_samples=7"]
    train(None, over, tmp_path / "straight", progress=False, deterministic=True)
    script = tmp_path / "kill.py"
    script.write_text(KILL_SCRIPT.format(repo=str(REPO), kill=5, overrides=over, out=str(tmp_path / "killed")))
    p = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert p.returncode == -9, p.stderr[-2000:]
    assert read_checkpoint(tmp_path / "killed" / "last.pt")["step"] == 4        # the last checkpoint before the kill
    rows = list(csv.DictReader(open(tmp_path / "killed" / "train.csv")))
    assert int(rows[-1]["step"]) == 5                                           # logged, then killed
    r = train(resume=tmp_path / "killed", progress=False, deterministic=True)
    assert r.step == 8
    a, b = _weights(tmp_path / "straight" / "last.pt"), _weights(tmp_path / "killed" / "last.pt")
    assert _same(a, b)
    ca, cb = read_checkpoint(tmp_path / "straight" / "last.pt"), read_checkpoint(tmp_path / "killed" / "last.pt")
    assert ca["epoch"] == cb["epoch"] and ca["batch_in_epoch"] == cb["batch_in_epoch"]
    assert _same(ca["optimizer"]["state"][0], cb["optimizer"]["state"][0])
    steps = [int(r["step"]) for r in csv.DictReader(open(tmp_path / "killed" / "train.csv"))]
    assert steps == list(range(1, 9))                                            # no duplicated rows
    with pytest.raises(ConfigError, match="cannot change in a resumed run"):
        train(resume=tmp_path / "killed", overrides=["optim.lr=1"], progress=False)


def test_empty_or_tiny_datasets_and_bad_resumes_are_refused(tmp_path):
    with pytest.raises(DatasetTooSmallError, match="training set too small: 1 scene"):
        train(None, TINY + ["data.synthetic_samples=1"], tmp_path / "a", progress=False)
    with pytest.raises(DatasetTooSmallError, match="batch 8"):
        train(None, TINY + ["data.synthetic_samples=3", "data.methods=['mf']", "optim.batch_size=8"],
              tmp_path / "b", progress=False)
    with pytest.raises(ConfigError, match="no last.pt"):
        train(resume=tmp_path / "nothing", progress=False)
    with pytest.raises(ConfigError, match="either a config"):
        train(tmp_path / "x.toml", resume=tmp_path / "a", progress=False)


DDP_SCRIPT = """
import sys
sys.path.insert(0, {repo!r})
from unwrap.learned.train import train
train(None, {overrides!r} + sys.argv[2:], sys.argv[1], progress=False)
"""


@pytest.mark.slow
def test_two_cpu_processes_with_batch_b_take_the_step_of_one_process_with_batch_2b(tmp_path):
    over = TINY + ["optim.steps=1", "optim.name=sgd", "optim.lr=0.05", "data.val_fraction=0", "run.val_every=100",
                   "data.synthetic_samples=8", "data.methods=['mf']"]
    script = tmp_path / "ddp.py"
    script.write_text(DDP_SCRIPT.format(repo=str(REPO), overrides=over))
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    one = subprocess.run([sys.executable, str(script), str(tmp_path / "one"), "optim.batch_size=4"],
                         capture_output=True, text=True, timeout=300, env=env)
    assert one.returncode == 0, one.stderr[-2000:]
    two = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
                          str(script), str(tmp_path / "two"), "optim.batch_size=2"],
                         capture_output=True, text=True, timeout=300, env=env)
    assert two.returncode == 0, two.stderr[-3000:]
    start = read_checkpoint(tmp_path / "one" / "last.pt")
    a, b = start["model"], _weights(tmp_path / "two" / "last.pt")
    assert _same(a, b, rtol=1e-4, atol=1e-6)
    summary = json.loads((tmp_path / "two" / "metrics.json").read_text())
    assert summary["world_size"] == 2
    assert not (tmp_path / "two" / "rank1").exists()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device (the CPU tests above pin run.device=cpu)")
def test_the_cuda_training_path_with_amp_trains_resumes_and_loads_on_the_cpu(tmp_path):
    """Where a GPU exists: the same tiny run on CUDA with mixed precision (autocast, and a gradient
    scaler for float16) writes its files, its losses are finite, its weights load on the
    CPU, and a resume continues from the saved step."""
    cuda = [o for o in TINY if not o.startswith("run.device=")] + ["run.device=cuda", "run.amp=true"]
    r = train(None, cuda + ["optim.steps=4"], tmp_path / "gpu", progress=False)
    assert r.step == 4
    rows = list(csv.DictReader(open(tmp_path / "gpu" / "train.csv")))
    losses = [float(row["loss"]) for row in rows]
    assert len(losses) == 4 and all(torch.isfinite(torch.tensor(losses)))
    model, ck = load_model(tmp_path / "gpu" / "model.pt")            # device="cpu"
    assert next(model.parameters()).device.type == "cpu"
    assert all(torch.isfinite(p).all() for p in model.parameters())
    r = train(resume=tmp_path / "gpu", overrides=["optim.steps=6"], progress=False)
    assert r.step == 6 and len(list(csv.DictReader(open(tmp_path / "gpu" / "train.csv")))) == 6
