"""Training loop of the fringe-order network (``calib train`` calls :func:`train`).

A run folder holds::

    config.toml      the resolved config (defaults <- file <- overrides)
    last.pt          full training state, written atomically every ``run.checkpoint_every`` steps
    best.pt          the same at the best validation error rate so far
    model.pt         the inference-only best model (what ships; see checkpoint.export_model)
    train.csv        step, epoch, loss and its parts, learning rate, samples/s, wall seconds
                     of this session, CPU seconds of the whole run (every log_every; CPU time is
                     what the run costs on dedicated cores, whatever else the machine runs)
    val.csv          step, validation loss, traditional and model error rates
    metrics.json     summary: final and best numbers, samples/s, wall time, data split
    metrics.png      training loss and validation error rate vs step
    log.txt          the log of the run

``resume=RUN`` continues a run from ``RUN/last.pt``: model, optimiser, scheduler, AMP scaler,
step, epoch, position in the epoch and every RNG state; data order and augmentation depend only
on (seed, epoch, index), so a killed and resumed run ends with the weights of an uninterrupted
one (tested). The loop runs under ``torchrun`` (DistributedDataParallel: gloo on CPU, NCCL on
CUDA; each rank a disjoint share of every epoch; only rank 0 writes) and uses mixed precision
(bfloat16 autocast, or float16 with a gradient scaler) on CUDA only; losses stay float32.
"""
from __future__ import annotations

import dataclasses
import json
import logging
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from . import features as Fe
from .checkpoint import FORMAT, FORMAT_VERSION, arch_from_config, build_model, export_model, read_checkpoint, save_atomic
from .config import TrainConfig, to_toml
from .data import ResumableSampler, build_datasets
from .distributed import device_for, dist_env, rng_state, seed_everything, set_deterministic, set_rng_state
from .errors import ConfigError, DatasetTooSmallError
from .losses import LossWeights, composite_loss
from .memory import check_training_memory, training_crop
from .metrics import ErrorCount
from .run_folder import (TRAIN_FIELDS, VAL_FIELDS, VAL_GROUP_FIELDS, RunFiles, attach_file_log, cpu_seconds, open_run,
                         plot_metrics)
from ..safe_output import write_text

log = logging.getLogger("unwrap.learned")

@dataclass
class TrainResult:
    """What a finished :func:`train` returns (rank 0; other ranks get ``run_dir`` None)."""
    run_dir: Path | None
    step: int
    best_error: float
    final_loss: float
    samples_per_s: float


def lr_factor(step: int, cfg) -> float:
    """Learning-rate multiplier: linear warm-up, then cosine to 2 % (or constant)."""
    o = cfg.optim
    w = o.warmup_steps
    if step < w:
        return (step + 1) / w
    if o.schedule == "constant":
        return 1.0
    t = min((step - w) / max(o.steps - w, 1), 1.0)
    return 0.02 + 0.98 * 0.5 * (1.0 + math.cos(math.pi * t))


def _to(batch: dict, device) -> dict:
    return {k: (v.to(device, non_blocking=True) if torch.is_tensor(v) else v) for k, v in batch.items()}


def training_step_loss(model, batch, cfg, weights: LossWeights, amp_dtype=None):
    """(loss, parts) of one batch: inputs -> network -> float32 composite loss."""
    kind, K = cfg.model.kind, cfg.model.max_correction
    x, _ = Fe.make_inputs(batch, kind)
    target, mask = Fe.targets(batch, kind, K)
    if amp_dtype is not None:
        with torch.autocast(device_type="cuda", dtype=amp_dtype):
            out = model(x)
    else:
        out = model(x)
    out = out.float()
    pred = Fe.expected_map(out, kind, K)
    return composite_loss(weights, pred, target, mask, logits=out, classes=Fe.class_targets(batch, kind, K))


@torch.no_grad()
def validate(model, val, cfg, weights, device) -> dict:
    """Loss and error rates (traditional and model) over the validation scenes, full frames.

    ``groups``: {group: (traditional, model) ErrorCount} over the parts of ``val`` that carry a
    ``group`` (``data.build_by_capture``: one per validation file); ``score``: what picks the best
    step, the pooled model error rate, or with ``run.val_score = "groups"`` the geometric mean of
    the groups' model error rates (:func:`group_score`: each kind of validation scene counts alike,
    whatever its pixel count or error level)."""
    model.eval()
    kind, K = cfg.model.kind, cfg.model.max_correction
    parts = getattr(val, "datasets", [val])
    trad, net, losses, groups = ErrorCount(), ErrorCount(), [], {}
    for part in parts:
        g = getattr(part, "group", None)
        loader = torch.utils.data.DataLoader(part, batch_size=1, shuffle=False, num_workers=0)
        for batch in loader:
            batch = _to(batch, device)
            loss, _ = training_step_loss(model, batch, cfg, weights)
            losses.append(float(loss))
            x, ok = Fe.make_inputs(batch, kind)
            order, _ = Fe.decode(model(x).float(), batch, kind, K)
            m = (ok & (batch["order_true"] >= 0)).cpu()
            t = ErrorCount.of(batch["order_traditional"].cpu(), batch["order_true"].cpu(), m)
            n = ErrorCount.of(order.cpu(), batch["order_true"].cpu(), m)
            trad, net = trad + t, net + n
            if g is not None:
                gt, gn = groups.get(g, (ErrorCount(), ErrorCount()))
                groups[g] = (gt + t, gn + n)
    model.train()
    score = group_score([gn for _, gn in groups.values()]) if cfg.run.val_score == "groups" and groups else net.rate
    return {"loss": float(np.mean(losses)) if losses else float("nan"), "error_traditional": trad.rate,
            "error_model": net.rate, "pixels": net.counted, "score": score, "groups": groups}


def group_score(counts) -> float:
    """Geometric mean of the error rates of ``counts`` (ErrorCount per validation group), each rate
    floored at half a pixel of its group (``0.5 / counted``: the count's resolution), so that a group
    with no wrong pixel weighs as one just under a pixel rather than pulling the mean to 0 (a floor
    of 1e-9 made any step with one error-free group the best, whatever the others). Groups with no
    counted pixel are left out; NaN when none is left."""
    rates = [max(c.rate, 0.5 / c.counted) for c in counts if c.counted]
    return float(np.exp(np.mean(np.log(rates)))) if rates else float("nan")


def _make_optimiser(model, cfg: TrainConfig, device):
    """(optimiser, LR scheduler, autocast dtype or None, gradient scaler or None)."""
    o = cfg.optim
    opt = torch.optim.AdamW(model.parameters(), lr=o.lr, weight_decay=o.weight_decay) if o.name == "adamw" \
        else torch.optim.SGD(model.parameters(), lr=o.lr, momentum=0.9, weight_decay=o.weight_decay)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: lr_factor(s, cfg))
    amp_dtype, scaler = None, None
    if device.type == "cuda" and cfg.run.amp:
        amp_dtype = torch.bfloat16 if torch.cuda.is_bf16_supported() else torch.float16
        if amp_dtype == torch.float16:
            scaler = torch.amp.GradScaler("cuda")
    return opt, sched, amp_dtype, scaler


def init_weights(model: str, arch: dict) -> dict:
    """The weights of checkpoint ``model`` ("learned": the shipped one; a model.pt / best.pt /
    last.pt path) for a fine-tuning run of architecture ``arch``: weights only (the optimiser,
    scheduler and step start fresh). Refuses (CheckpointError) a checkpoint of another kind or
    architecture, naming the fields that differ."""
    from .checkpoint import ARCH_OPTIONAL, load_model
    from .errors import CheckpointError
    from .infer import shipped_model_path

    path = shipped_model_path() if model in ("learned", "default") else Path(model)
    ck = read_checkpoint(path)
    theirs = ck["arch"]
    if theirs.get("kind") != arch["kind"]:
        raise CheckpointError(f"model.init {path}: a {theirs.get('kind')!r} model, this run trains a "
                              f"{arch['kind']!r} model (model.kind): fine-tuning keeps the kind")
    diff = {k: (theirs.get(k, ARCH_OPTIONAL.get(k)), arch.get(k, ARCH_OPTIONAL.get(k))) for k in dict.fromkeys([*arch, *theirs])}
    diff = {k: ab for k, ab in diff.items() if ab[0] != ab[1]}         # an absent optional key is its default
    if diff:
        raise CheckpointError(f"model.init {path}: another architecture than this run's [model] ("
                              + ", ".join(f"{k}: checkpoint {a}, run {b}" for k, (a, b) in diff.items())
                              + "); set the [model] keys to the checkpoint's")
    net, _ = load_model(ck)
    return net.state_dict()


# ---------------------------------------------------------------- the loop
class _Session:
    """One training session (new or resumed): model, optimiser, counters, timing and, on rank 0,
    the run folder's files. :func:`train` drives it batch by batch."""

    def __init__(self, cfg: TrainConfig, run_dir: Path, resume, rank: int, world: int, local_rank: int, device, info: dict):
        self.cfg, self.run_dir, self.world, self.device, self.info = cfg, run_dir, world, device, info
        self.writer = rank == 0
        self.arch = arch_from_config(cfg.model)
        self.model = build_model(self.arch).to(device)
        self.opt, self.sched, self.amp_dtype, self.scaler = _make_optimiser(self.model, cfg, device)
        self.step, self.epoch, self.batch_in_epoch, self.best, self.cpu_before = 0, 0, 0, float("inf"), 0.0
        if resume is not None:
            self._restore(read_checkpoint(run_dir / "last.pt"))
        elif cfg.model.init:
            self.model.load_state_dict(init_weights(cfg.model.init, self.arch))
        self.net = torch.nn.parallel.DistributedDataParallel(
            self.model, device_ids=[local_rank] if device.type == "cuda" else None) if world > 1 else self.model
        self.weights = cfg.loss
        d = cfg.data
        self.meta = {"methods": list(d.methods), "orientations": list(d.orientations),
                     "frequencies": {m: list(d.frequencies(m)) for m in d.methods},
                     "data": list(d.train) or f"synthetic:{d.synthetic_samples}",
                     "val_scenes": info["val_scenes"], "loss": dataclasses.asdict(cfg.loss)}
        self.files = self.handler = None
        self.total = int(cfg.optim.steps)
        if resume is not None and self.step >= self.total:
            raise ConfigError(f"--resume {run_dir}: the run is at step {self.step} and optim.steps is {self.total}; "
                              f"nothing to train (give optim.steps=N with N > {self.step} to train further)")
        self.t_train, self.n_seen, self.last_loss, self.val_row = 0.0, 0, float("nan"), None

    def _restore(self, ck: dict):
        self.model.load_state_dict(ck["model"])
        self.opt.load_state_dict(ck["optimizer"])
        self.sched.load_state_dict(ck["scheduler"])
        if self.scaler is not None and ck.get("scaler"):
            self.scaler.load_state_dict(ck["scaler"])
        self.step, self.epoch, self.batch_in_epoch, self.best = ck["step"], ck["epoch"], ck["batch_in_epoch"], ck["best"]
        self.cpu_before = float(ck.get("cpu_s", 0.0))
        set_rng_state(ck["rng"])

    def open_files(self, resumed: bool, steps_per_epoch: int):
        """Rank 0: the resolved config, the CSV logs (cut back to the checkpoint), log.txt."""
        if self.writer:
            self.run_dir.mkdir(parents=True, exist_ok=True)
            write_text(self.run_dir / "config.toml", to_toml(self.cfg))
            self.files = RunFiles(self.run_dir, self.step if resumed else None)
            self.handler = attach_file_log(self.run_dir)
            log.info("%s run %s: %d training items (%d scenes), %d validation items, %d step(s)/epoch, world %d, "
                     "device %s%s", "resumed" if resumed else "new", self.run_dir, self.info["train_items"],
                     len(self.info["train_scenes"]), self.info["val_items"], steps_per_epoch, self.world,
                     self.device, f", step {self.step}" if resumed else "")
        self.t_start, self.cpu_start = time.perf_counter(), cpu_seconds()

    def cpu_s(self) -> float:
        return self.cpu_before + cpu_seconds() - self.cpu_start

    def state(self) -> dict:
        return {"format": FORMAT, "format_version": FORMAT_VERSION, "arch": self.arch,
                "model": self.model.state_dict(), "meta": {**self.meta, "step": self.step},
                "optimizer": self.opt.state_dict(), "scheduler": self.sched.state_dict(),
                "scaler": self.scaler.state_dict() if self.scaler is not None else {}, "step": self.step,
                "epoch": self.epoch, "batch_in_epoch": self.batch_in_epoch, "best": self.best, "rng": rng_state(),
                "cpu_s": self.cpu_s(), "config": to_toml(self.cfg)}

    def optimise(self, batch: dict, bs: int) -> dict:
        """One optimiser step on a batch; returns the loss parts."""
        t0 = time.perf_counter()
        batch = _to(batch, self.device)
        loss, parts = training_step_loss(self.net, batch, self.cfg, self.weights, self.amp_dtype)
        if not torch.isfinite(loss):
            raise DatasetTooSmallError(f"step {self.step}: the loss is not finite ({float(loss)}); the batch "
                                       "has no usable pixels or the learning rate is too high")
        self.opt.zero_grad(set_to_none=True)
        if self.scaler is not None:
            self.scaler.scale(loss).backward()
            self.scaler.unscale_(self.opt)
        else:
            loss.backward()
        if self.cfg.optim.grad_clip > 0:
            torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.cfg.optim.grad_clip)
        if self.scaler is not None:
            self.scaler.step(self.opt)
            self.scaler.update()
        else:
            self.opt.step()
        self.sched.step()
        self.step += 1
        self.batch_in_epoch += 1
        self.t_train += time.perf_counter() - t0
        self.n_seen += bs * self.world
        self.last_loss = float(loss.detach())
        return parts

    def samples_per_s(self) -> float:
        return self.n_seen / self.t_train if self.t_train > 0 else 0.0

    def record(self, parts: dict, bar, val_ds):
        """Rank 0 after a step: CSV row, progress bar, validation + best.pt, last.pt."""
        run, step, last = self.cfg.run, self.step, self.step == self.total
        if step % run.log_every == 0 or last:
            self.files.append("train.csv", TRAIN_FIELDS, {
                "step": step, "epoch": self.epoch, "loss": f"{self.last_loss:.6g}",
                **{k: f"{v:.6g}" for k, v in parts.items()}, "lr": f"{self.sched.get_last_lr()[0]:.6g}",
                "samples_per_s": f"{self.samples_per_s():.4g}", "time_s": f"{time.perf_counter() - self.t_start:.1f}",
                "cpu_s": f"{self.cpu_s():.1f}"})
        bar.update(step - bar.n)
        bar.set_postfix(loss=f"{self.last_loss:.4g}", samples_per_s=f"{self.samples_per_s():.4g}", refresh=False)
        if val_ds is not None and (step % run.val_every == 0 or last):
            self.val_row = validate(self.model, val_ds, self.cfg, self.weights, self.device)
            self.files.append("val.csv", VAL_FIELDS, {"step": step, **self.val_row})
            log.info("step %d: val loss %.4g, error traditional %.4f %%, model %.4f %%", step, self.val_row["loss"],
                     100 * self.val_row["error_traditional"], 100 * self.val_row["error_model"])
            for g, (gt, gn) in self.val_row.pop("groups").items():
                self.files.append("val_groups.csv", VAL_GROUP_FIELDS, {
                    "step": step, "group": g, "error_traditional": gt.rate, "error_model": gn.rate, "pixels": gn.counted})
                log.info("step %d: %s: error traditional %.4f %%, model %.4f %% (%d pixels)", step, g,
                         100 * gt.rate, 100 * gn.rate, gn.counted)
            score = self.val_row.pop("score")
            if score == score and score < self.best:
                self.best = score
                save_atomic(self.state(), self.run_dir / "best.pt")
        if step % run.checkpoint_every == 0 or last:
            save_atomic(self.state(), self.run_dir / "last.pt")

    def finish(self, bar):
        """Rank 0 at the end: last.pt, model.pt (when complete), metrics.json, metrics.png."""
        run_dir = self.run_dir
        save_atomic(self.state(), run_dir / "last.pt")
        bar.update(self.step - bar.n)
        bar.set_postfix(loss=f"{self.last_loss:.4g}")
        bar.close()
        if self.step >= self.total:
            src = run_dir / "best.pt" if (run_dir / "best.pt").exists() else run_dir / "last.pt"
            export_model(read_checkpoint(src), run_dir / "model.pt")
        info = self.info
        summary = {"run": str(run_dir), "step": self.step, "steps": self.total, "final_loss": self.last_loss,
                   "best_val_error": None if self.best == float("inf") else self.best, "last_val": self.val_row,
                   "train_samples_per_s": self.samples_per_s(), "world_size": self.world, "device": str(self.device),
                   "threads": torch.get_num_threads(), "wall_s_this_session": time.perf_counter() - self.t_start,
                   "cpu_s_total": self.cpu_s(), "train_items": info["train_items"], "val_items": info["val_items"],
                   "train_scenes": len(info["train_scenes"]), "val_scenes": info["val_scenes"]}
        write_text(run_dir / "metrics.json", json.dumps(summary, indent=1))
        plot_metrics(run_dir)
        log.removeHandler(self.handler)
        self.handler.close()


def train(config=None, overrides=(), out_dir=None, *, resume=None, deterministic: bool | None = None,
          progress: bool = True, stop_after: int | None = None, on_step=None) -> TrainResult:
    """Train (or resume) a fringe-order network; see the module docstring for the run folder.

    ARGUMENTS
    - config: TOML file (or None for the defaults); overrides: ``section.key=value`` strings.
    - out_dir: the run folder (created); resume: an existing run folder to continue (then
      ``config`` must be None and only :data:`RESUMABLE_OVERRIDES` may be overridden).
    - deterministic: force ``run.deterministic`` on / off; progress: show the bar.
    - stop_after: stop (after writing last.pt) once this step is reached - for time-boxed
      sessions; on_step: optional ``callback(step, loss)`` after every step (rank 0).
    RETURNED VALUE: :class:`TrainResult`.
    """
    rank, world, local_rank = dist_env()
    cfg, run_dir = open_run(config, overrides, out_dir, resume)
    check_training_memory(cfg, arch_from_config(cfg.model), training_crop(cfg))   # before any allocation
    if deterministic is not None:
        cfg = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, deterministic=bool(deterministic)))
    set_deterministic(cfg.run.deterministic)
    if cfg.run.threads:
        torch.set_num_threads(int(cfg.run.threads))
    device = device_for(cfg, local_rank)
    if world > 1 and not torch.distributed.is_initialized():
        torch.distributed.init_process_group("nccl" if device.type == "cuda" else "gloo")
    seed = int(cfg.run.seed)
    seed_everything(seed)

    train_ds, val_ds, info = build_datasets(cfg)
    bs = int(cfg.optim.batch_size)
    sampler = ResumableSampler(len(train_ds), seed=seed, rank=rank, world=world)
    if sampler.per_rank() < bs:
        raise DatasetTooSmallError(f"training set too small: {len(train_ds)} items for {world} process(es) x "
                                   f"batch {bs}; lower optim.batch_size or add data")
    steps_per_epoch = sampler.per_rank() // bs
    s = _Session(cfg, run_dir, resume, rank, world, local_rank, device, info)
    s.open_files(resume is not None, steps_per_epoch)
    bar = tqdm(total=s.total, initial=s.step, desc="train", unit="step", file=sys.stderr,
               disable=not (progress and s.writer), dynamic_ncols=True)
    s.model.train()
    stop = s.total if stop_after is None else min(s.total, stop_after)
    while s.step < stop:
        sampler.set_epoch(s.epoch, s.batch_in_epoch * bs)
        train_ds.set_epoch(s.epoch)
        loader = torch.utils.data.DataLoader(train_ds, batch_size=bs, sampler=sampler, drop_last=True,
                                             num_workers=int(cfg.data.workers), persistent_workers=False)
        for batch in loader:
            parts = s.optimise(batch, bs)
            if s.writer:
                s.record(parts, bar, val_ds)
                if on_step is not None:
                    on_step(s.step, s.last_loss)
            if s.step >= stop:
                break
        if s.step >= stop:
            break
        s.epoch, s.batch_in_epoch = s.epoch + 1, 0
    if s.batch_in_epoch >= steps_per_epoch:   # the loop ended exactly at an epoch's end
        s.epoch, s.batch_in_epoch = s.epoch + 1, 0
    if s.writer:
        s.finish(bar)
    return TrainResult(run_dir if s.writer else None, s.step, s.best, s.last_loss, s.samples_per_s())
