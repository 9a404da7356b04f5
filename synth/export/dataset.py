"""Export the twin's training data: ``export_dataset(config, out)`` renders every sample of a shard
and writes it crash-safely (synth.export.writer) in the schema of unwrap.dataset_schema.

SYNOPSIS

    from synth.export.dataset import export_dataset
    summary = export_dataset("synth/data/export_train.toml", "data/train.h5")          # one shard
    summary = export_dataset(cfg, "data/train.h5", shard=(2, 8))   # data/train-00002-of-00008.h5
    print(format_summary(summary))

The shard (i, n) comes from the argument, else from torchrun's RANK/WORLD_SIZE or a SLURM
array's SLURM_ARRAY_TASK_ID/COUNT, else (0, 1). Samples are split into n contiguous blocks; sample
i depends only on (seed, i), so 1 shard or n shards hold bit-identical samples.
"""
from __future__ import annotations

import json
import logging
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from unwrap.dataset_schema import SCHEMA, SCHEMA_VERSION

from .config import ExportConfig, load_config
from .sample import make_sample, params_json
from .scenes import check_meshes
from .writer import ShardWriter, fingerprint_of, shard_from_environment, shard_path, shard_range

LOG = logging.getLogger("synth")


def code_version() -> str:
    """``git describe --always --dirty`` of the source tree, or "unknown"."""
    try:
        r = subprocess.run(["git", "describe", "--always", "--dirty", "--tags"], cwd=Path(__file__).parent,
                           capture_output=True, text=True, timeout=10)
        return r.stdout.strip() or "unknown"
    except (OSError, subprocess.TimeoutExpired):
        return "unknown"


def base_system(cfg: ExportConfig):
    """The config's system (built-in default or files), ideal if asked; and the posterior sampler."""
    from calib import default_system
    from calib.io import load_system

    from .posterior import PosteriorSampler
    from ..scenes.scene import ideal_system

    system = load_system([cfg.base_dir / f for f in cfg.system_file]) if cfg.system_file else default_system()
    if cfg.ideal:
        system = ideal_system(system)
    sampler = PosteriorSampler(system, cfg.base_dir / cfg.system_file[0]) if cfg.perturb == "posterior" else None
    return system, sampler


def dataset_attrs(cfg: ExportConfig, system) -> dict:
    """Root attributes of every shard of this export (unwrap.dataset_schema)."""
    from calib.io.calibration_json import system_to_dict

    Wp, Hp = system.projector.size
    sys_json = json.dumps(system_to_dict(system))
    cfg_json = json.dumps(cfg.to_dict(), sort_keys=True)
    return {"schema": SCHEMA, "schema_version": SCHEMA_VERSION, "kind": "twin",
            "orientations": list(cfg.orientations), "frequencies": list(cfg.frequencies), "steps": list(cfg.steps),
            "widths": json.dumps({"v": Wp, "h": Hp}), "camera_size": list(system.camera.size),
            "bits": int(cfg.effects.get("bits", 8)), "min_modulation": cfg.min_modulation, "system": sys_json,
            "config": cfg.text, "config_json": cfg_json, "seed": cfg.seed, "code_version": code_version(),
            "codec": cfg.codec, "samples_total": cfg.samples, "units": "mm, px, rad",
            "fingerprint": fingerprint_of(cfg_json, sys_json, SCHEMA_VERSION)}


def export_dataset(config, out, *, shard=None, progress: bool = True, overrides=()) -> dict:
    """Export one shard of ``config`` (path or ExportConfig; ``overrides``: ``section.key=value``
    strings applied to a path's TOML) to ``out`` (see the module docstring). Resumes an
    interrupted run. Returns the summary dict (:func:`format_summary`)."""
    cfg = load_config(config, overrides) if not isinstance(config, ExportConfig) else config
    check_meshes(cfg)
    system, sampler = base_system(cfg)
    i, n = shard if shard is not None else (shard_from_environment() or (0, 1))
    indices = shard_range(cfg.samples, i, n)
    path = shard_path(out, i, n)
    attrs = {**dataset_attrs(cfg, system), "shard": [i, n]}
    groups = {o: {"frequencies": list(cfg.frequencies), "steps": list(cfg.steps)} for o in cfg.orientations}
    writer = ShardWriter(path, indices, attrs, cfg.codec, attrs["fingerprint"], groups)
    stages = {k: 0.0 for k in ("geometry", "patterns", "noise", "phase", "labels", "write")}
    t0 = time.perf_counter()
    if writer.complete():
        LOG.info("%s is complete already (%d samples)", path, len(indices))
        return summarize(path, stages, 0, time.perf_counter() - t0)
    todo = writer.prepare()
    label = f"export {path.name}" + (f" (shard {i}/{n})" if n > 1 else "")
    with tqdm(total=len(indices), initial=len(indices) - len(todo), desc=label, unit="sample",
              file=sys.stderr, disable=not progress, dynamic_ncols=True) as bar:
        for index in todo:
            sample = make_sample(cfg, system, index, sampler)
            for k, v in sample.timings.items():
                stages[k] += v
            t = time.perf_counter()
            writer.write_part(index, sample.arrays, params_json(sample), sample.label_check)
            stages["write"] += time.perf_counter() - t
            bar.update()
    t = time.perf_counter()
    writer.assemble()
    stages["write"] += time.perf_counter() - t
    return summarize(path, stages, len(todo), time.perf_counter() - t0)


def summarize(path, stages: dict, rendered: int, seconds: float) -> dict:
    """Samples, bytes, compression ratio, label-check totals and time per stage of a shard file."""
    import h5py

    path = Path(path)
    with h5py.File(path, "r") as h5:
        S = int(h5.attrs["n_samples"])
        raw = 0
        def add(name, obj):
            nonlocal raw
            if isinstance(obj, h5py.Dataset) and name != "params":
                raw += int(np.prod(obj.shape)) * obj.dtype.itemsize
        h5.visititems(add)
        lc = h5["label_check"][...]
        orients = [str(o) for o in h5.attrs["orientations"]]
        freqs = [float(f) for f in h5.attrs["frequencies"]]
        valid_lit = 0
        lit_bit = 2
        for k in range(S):
            valid_lit += int((h5["masks"][k] & lit_bit).astype(bool).sum())
    size = path.stat().st_size
    checks = {}
    for a, o in enumerate(orients):
        for b, f in enumerate(freqs):
            if lc[:, a, b, 0].min() >= 0:
                checks[f"{o} 1->{f:g}"] = {"clean_interior": int(lc[:, a, b, 0].sum()), "clean_edge": int(lc[:, a, b, 1].sum()),
                                           "effects_interior": int(lc[:, a, b, 2].sum()),
                                           "effects_edge": int(lc[:, a, b, 3].sum())}
    return {"file": str(path), "samples": S, "rendered_now": rendered, "bytes": size, "raw_bytes": raw,
            "compression_ratio": raw / max(size, 1), "bytes_per_sample": size / max(S, 1), "lit_pixels": valid_lit,
            "label_check": checks, "stage_seconds": stages, "seconds": seconds}


def format_summary(s: dict) -> str:
    """The summary as printed by ``calib export``."""
    lines = [f"{s['file']}: {s['samples']} samples ({s['rendered_now']} rendered now) in {s['seconds']:.1f} s",
             f"  size {s['bytes'] / 1e6:.1f} MB ({s['bytes_per_sample'] / 1e6:.2f} MB/sample), uncompressed "
             f"{s['raw_bytes'] / 1e6:.1f} MB, compression ratio {s['compression_ratio']:.2f}"]
    total = sum(s["stage_seconds"].values())
    if total > 0:
        lines.append("  time per stage: " + ", ".join(f"{k} {v:.1f} s ({100 * v / total:.0f} %)"
                                                      for k, v in s["stage_seconds"].items()))
    if s["label_check"]:
        lines.append(f"  label check (traditional MF on the noise-free render vs geometric order; "
                     f"{s['lit_pixels']} lit pixels per orientation):")
        for k, v in s["label_check"].items():
            lines.append(f"    {k}: clean render {v['clean_interior']} interior / {v['clean_edge']} edge mismatches; "
                         f"with effects {v['effects_interior']} / {v['effects_edge']}")
    return "\n".join(lines)
