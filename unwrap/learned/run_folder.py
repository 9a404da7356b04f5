"""The run folder of a training run (layout: :mod:`unwrap.learned.train`): opening a new run or the
one ``--resume`` continues (only some keys may change), the CSV logs cut back to the checkpoint,
log.txt, metrics.png, and the CPU seconds the run costs."""
from __future__ import annotations

import csv
import io
import logging
import os
import time
from pathlib import Path

from .config import TrainConfig, resolve_config
from .errors import ConfigError
from ..safe_output import save_figure, write_text

log = logging.getLogger("unwrap.learned")

#: What may change when a run is resumed (everything else must match the saved config).
RESUMABLE_OVERRIDES = ("optim.steps", "run.log_every", "run.val_every", "run.checkpoint_every", "run.threads",
                       "data.workers")
TRAIN_FIELDS = ("step", "epoch", "loss", "mse", "fourier", "ce", "lr", "samples_per_s", "time_s", "cpu_s")
VAL_FIELDS = ("step", "loss", "error_traditional", "error_model", "pixels")
VAL_GROUP_FIELDS = ("step", "group", "error_traditional", "error_model", "pixels")   # val_groups.csv (by-file validation)


class RunFiles:
    """The run folder's logs (rank 0 only)."""

    def __init__(self, run_dir: Path, resume_step: int | None):
        self.dir = run_dir
        for name, fields in (("train.csv", TRAIN_FIELDS), ("val.csv", VAL_FIELDS), ("val_groups.csv", VAL_GROUP_FIELDS)):
            path = run_dir / name
            if name == "val_groups.csv" and not path.exists():
                continue
            rows = []
            if resume_step is not None and path.exists():   # drop rows written after the checkpoint
                with open(path, newline="") as fh:
                    rows = [r for r in csv.DictReader(fh) if int(r["step"]) <= resume_step]
            buf = io.StringIO(newline="")
            w = csv.DictWriter(buf, fieldnames=fields)
            w.writeheader()
            w.writerows(rows)
            write_text(path, buf.getvalue())     # atomic: a crash here leaves the old log, not half of it

    def append(self, name: str, fields, row: dict):
        new = not (self.dir / name).exists()
        with open(self.dir / name, "a", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=fields)
            if new:
                w.writeheader()
            w.writerow({k: row.get(k, "") for k in fields})

    def read(self, name: str) -> list[dict]:
        with open(self.dir / name, newline="") as fh:
            return list(csv.DictReader(fh))


def plot_metrics(run_dir: Path) -> Path | None:
    """metrics.png: training loss and validation error rates vs step."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = RunFiles.__new__(RunFiles)
    files.dir = run_dir
    tr, va = files.read("train.csv"), files.read("val.csv")
    if not tr:
        return None
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    ax[0].semilogy([int(r["step"]) for r in tr], [float(r["loss"]) for r in tr], lw=1)
    ax[0].set(xlabel="step", ylabel="training loss", title="loss")
    if va:
        s = [int(r["step"]) for r in va]
        ax[1].plot(s, [100 * float(r["error_traditional"]) for r in va], "k--", label="traditional")
        ax[1].plot(s, [100 * float(r["error_model"]) for r in va], "o-", label="model")
        ax[1].legend()
    ax[1].set(xlabel="step", ylabel="fringe-order error rate [%]", title="validation")
    fig.tight_layout()
    path = run_dir / "metrics.png"
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path


def resume_config(run_dir: Path, overrides) -> TrainConfig:
    saved = resolve_config(run_dir / "config.toml")
    for text in overrides or ():
        name = text.split("=", 1)[0].strip()
        if name not in RESUMABLE_OVERRIDES:
            raise ConfigError(f"--resume: {name!r} cannot change in a resumed run (allowed: "
                              f"{', '.join(RESUMABLE_OVERRIDES)})")
    return resolve_config(run_dir / "config.toml", overrides) if overrides else saved


def attach_file_log(run_dir: Path):
    h = logging.FileHandler(run_dir / "log.txt")
    h.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
    log.addHandler(h)
    log.setLevel(logging.INFO)
    return h


def cpu_seconds() -> float:
    """CPU seconds of this process plus its finished children (the data-loading workers of the
    epochs so far: a worker's time is counted once it has been joined, at its epoch's end)."""
    t = os.times()
    return time.process_time() + t.children_user + t.children_system


def open_run(config, overrides, out_dir, resume) -> tuple[TrainConfig, Path]:
    """(resolved config, run folder) of a new run or of the run ``resume`` continues."""
    if resume is not None:
        if config is not None:
            raise ConfigError("give either a config (new run) or --resume RUN, not both")
        run_dir = Path(resume)
        if not (run_dir / "last.pt").is_file():
            raise ConfigError(f"--resume {run_dir}: no last.pt there (not a run folder, or it never saved)")
        return resume_config(run_dir, overrides), run_dir
    cfg = resolve_config(config, overrides)
    run_dir = Path(out_dir) if out_dir is not None else Path("runs") / time.strftime("%Y%m%d-%H%M%S")
    if (run_dir / "last.pt").exists():
        raise ConfigError(f"{run_dir} already holds a run (last.pt); use --resume {run_dir} or another -o")
    begun = [n for n in ("config.toml", "train.csv", "val.csv", "log.txt") if (run_dir / n).exists()]
    if begun:   # a run that never saved a checkpoint: its files would be mixed with this one's
        raise ConfigError(f"{run_dir} holds the start of another run ({', '.join(begun)}, no checkpoint); "
                          "remove it or choose another -o")
    return cfg, run_dir
