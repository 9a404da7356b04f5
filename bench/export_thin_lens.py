"""The thin lens in the dataset export against the blur, on the same scenes: ``python -m
bench.export_thin_lens --work DIR [--samples 4] [--points 8 16 32]``; ``--config
synth/data/export_real.toml [--index 0] --points 8 [--exact]``: the cost of one sample of a config
with the blur and with the thin lens (config_cost; ``--exact``: also with the interreflection
computed per aperture point instead of shared, synth.effects.lens_indirect); ``--quick``: 1 sample, blur vs 4 points.

Writes one export config per variant to ``DIR`` (real-like scenes: 1-2 procedural objects before a
wall or on a table, the built-in camera's central 320 x 240 window at the real pixel scale,
camera and projector defocus with apertures of 2-6 mm and focus -150..150 mm from the world
origin's depth, v fringes at f = 1, 48 with 12 steps, no noise and 16 bits so the stored phase is
the render's; no interreflection or subsurface, so that only the defocus model differs) and exports
each with ``calib export``'s own function (synth.export.dataset.export_dataset; ``calib export
DIR/blur.toml -o DIR/blur.h5`` is the same). The variants differ only in ``samples`` of the two
defocus tables (absent: the blur; a fixed number draws no random number, so every variant has
the same scenes, checked).

Per variant: wall and process CPU seconds per sample (the export's whole work: render, phase,
labels, write; the variants exported round robin, one sample each in turn, the blur the anchor,
after an untimed warm-up sample), the model that ran (params "defocus"),
and the bias of the unit-frequency phase against the truth, ``e = wrap(phi_1 - 2 pi c / width)
* 48 / (2 pi)`` in periods of the f = 48 fringe (|e| > 0.5: a wrong MF 1 -> 48 order), on the lit,
valid pixels within ``--band`` px of an outline (the export's edge mask: object, lit state or
depth jump, dilated) and beyond it: RMS, the share over half a fringe, and the correlation of
the band's bias with the largest ``--points`` variant's (the reference). The label check's
counts (sample.py: MF 1 -> 48 on the noise-free render with effects, interior / within 1 px of an
edge) are printed as well.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import time
from collections import Counter
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
F_HIGH = 48


def _config(samples: int, n: int, seed: int) -> str:
    dof = "aperture_mm = [2, 6], focus_offset_mm = [-150, 150]" + (f", samples = {samples}" if samples else "")
    return f"""# bench.export_thin_lens variant: {'blur' if not samples else f'thin lens, {samples} points'}
[export]
samples = {n}
seed = {seed}
min_object_fraction = 0.08

[system]
file = "{REPO / 'synth' / 'data' / 'system_window320.json'}"

[patterns]
orientations = ["v"]
frequencies = [1, {F_HIGH}]
steps = 12

[scene]
objects = [1, 2]
procedural = ["sphere", "blobs", "heightfield", "steps"]
size_mm = [30, 90]
albedo = [0.2, 0.95]
texture = 0.0
layouts = ["wall", "table"]
wall_gap_mm = [2, 60]
wall_albedo = [0.4, 0.95]
table_wall = 0.5

[effects]
exposure = [0.6, 0.9]
projector_defocus = {{{dof}}}
camera_defocus = {{{dof}}}
bits = 16
"""


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _dilate(mask: np.ndarray, r: int) -> np.ndarray:
    import cv2

    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    return cv2.dilate(mask.astype(np.uint8), k) > 0


def bias_maps(path: Path, band: int):
    """(bias (S, H, W) in f = 48 periods, NaN where not lit / valid; band mask; interior mask;
    params list; label_check (S, O, F, 4))."""
    import h5py

    from unwrap.dataset_schema import FLAG_LOW_MODULATION, MASK_EDGE, MASK_LIT, decode_phase

    with h5py.File(path, "r") as h5:
        ph1 = decode_phase(h5["v/phase"][:, 0])
        flags = h5["v/flags"][:, 0]
        coord = h5["v/coordinate"][...].astype(np.float64)
        masks = h5["masks"][...]
        params = [json.loads(p) for p in h5["params"][...]]
        check = h5["label_check"][...]
        width = 912.0
    truth = 2 * np.pi * coord / width
    e = np.angle(np.exp(1j * (ph1 - truth))) * F_HIGH / (2 * np.pi)
    ok = ((masks & MASK_LIT) > 0) & ((flags & FLAG_LOW_MODULATION) == 0) & np.isfinite(coord)
    e = np.where(ok, e, np.nan)
    near = np.stack([_dilate((m & MASK_EDGE) > 0, band) for m in masks])
    return e, ok & near, ok & ~near, params, check


def _stats(e, mask, ref=None):
    v = e[mask]
    out = {"pixels": int(v.size), "rms": float(np.sqrt(np.mean(v ** 2))) if v.size else float("nan"),
           "p99": float(np.percentile(np.abs(v), 99)) if v.size else float("nan"),
           "wrong_pct": 100.0 * float(np.mean(np.abs(v) > 0.5)) if v.size else float("nan")}
    if ref is not None:
        r = ref[mask]
        out["corr"] = float(np.corrcoef(v, r)[0, 1]) if v.size > 2 and np.std(v) > 0 and np.std(r) > 0 else float("nan")
    return out


def run(work: Path, samples: int, points, seed: int, band: int) -> list:
    """Export every variant one sample at a time, round robin (one-sample shards, the starting
    variant rotating), so that a changing load on shared cores falls on all variants alike; then
    join each variant's shards (writer.combine) and measure its bias."""
    from synth.export.dataset import export_dataset
    from synth.export.writer import combine, shard_path

    work.mkdir(parents=True, exist_ok=True)
    names = {n: "blur" if not n else f"lens{n}" for n in [0, *points]}
    for n, name in names.items():
        (work / f"{name}.toml").write_text(_config(n, samples, seed))
        for p in [work / f"{name}.h5", *work.glob(f"{name}-*-of-*.h5*"), *work.glob(f"warmup/{name}*")]:
            shutil.rmtree(p) if p.is_dir() else p.unlink(missing_ok=True)
    wall, cpu = dict.fromkeys(names.values(), 0.0), dict.fromkeys(names.values(), 0.0)
    stages = {name: {} for name in names.values()}
    # untimed warm-up (one-off compilations in the thin lens's first call would fall on one variant)
    for name in {names[0], names[min(points)] if points else names[0]}:
        export_dataset(work / f"{name}.toml", work / "warmup" / f"{name}.h5", shard=(0, samples), progress=False)
    order = list(names.items())
    for i in range(samples):
        for n, name in order[i % len(order):] + order[:i % len(order)]:
            t0, c0 = time.perf_counter(), _cpu()
            s = export_dataset(work / f"{name}.toml", work / f"{name}.h5", shard=(i, samples), progress=False)
            wall[name] += time.perf_counter() - t0
            cpu[name] += _cpu() - c0
            for k, v in s.get("stage_seconds", {}).items():
                stages[name][k] = stages[name].get(k, 0.0) + v
    rows, maps = [], {}
    for n, name in names.items():
        out = work / f"{name}.h5"
        if samples > 1:  # one shard is the file itself
            combine([shard_path(out, i, samples) for i in range(samples)], out)
        e, near, inner, params, check = bias_maps(out, band)
        maps[name] = (e, near, inner, params)
        models = Counter(f"{d.split('_')[0]} {v['model']}" for p in params for d, v in p.get("defocus", {}).items())
        rows.append({"variant": name, "samples": samples, "wall_s": wall[name] / samples,
                     "cpu_s": cpu[name] / samples, "stages": stages[name], "models": dict(sorted(models.items())),
                     "check": check.sum(0).tolist()})
    ref_name = f"lens{max(points)}" if points else "blur"
    base = [dict(p, effects=None, plan=None, defocus=None) for p in maps["blur"][3]]
    # the same pixels for every variant: lit and valid in all of them
    common = np.logical_and.reduce([np.isfinite(m[0]) for m in maps.values()])
    ref = maps[ref_name][0]
    for r in rows:
        e, near, inner, params = maps[r["variant"]]
        r["same_scenes"] = [dict(p, effects=None, plan=None, defocus=None) for p in params] == base
        r["band"] = _stats(e, near & common, ref)
        r["interior"] = _stats(e, inner & common, ref)
    return rows


def config_cost(config: Path, index: int, points, exact: bool = False, warmup: bool = True) -> list:
    """CPU and wall seconds of sample ``index`` of ``config`` (e.g. synth/data/export_real.toml)
    with the blur (``samples`` = 0 on both devices) and with ``samples`` = each of ``points`` on
    both devices (the interreflection shared between aperture points, synth.effects.lens_indirect;
    with ``exact`` also computed per aperture point), the same scene, after an untimed warm-up
    sample with the blur; the export's stage seconds and the models that ran."""
    from dataclasses import replace as _replace
    from unittest import mock

    from synth.export import scenes as export_scenes
    from synth.export.config import load_config
    from synth.export.dataset import base_system
    from synth.export.sample import make_sample

    from synth.effects.spec import Interreflection

    def exact_ir(*args, **kw):
        return _replace(Interreflection(*args, **kw), thin_lens="exact")

    rows = []
    variants = [(0, "shared")] * (2 if warmup else 1) + [(n, m) for n in points
                                                         for m in (("shared", "exact") if exact else ("shared",))]
    for k, (n, mode) in enumerate(variants):
        sets = [f"effects.{d}.samples={n}" for d in ("camera_defocus", "projector_defocus")]
        cfg = load_config(config, sets)
        system, sampler = base_system(cfg)
        t0, c0 = time.perf_counter(), _cpu()
        # the export draws its interreflection table without the option: "exact" patched in here
        with mock.patch.object(export_scenes, "Interreflection", exact_ir if mode == "exact" else Interreflection):
            s = make_sample(cfg, system, index, sampler)
        if warmup and k == 0:
            continue
        rows.append({"variant": "blur" if not n else f"lens{n}" + (", exact indirect" if mode == "exact" else ""),
                     "cpu_s": _cpu() - c0,
                     "wall_s": time.perf_counter() - t0, "stages": s.timings, "defocus": s.params.get("defocus"),
                     "interreflection": s.params["effects"].get("interreflection"),
                     "layout": s.params.get("layout", {}).get("kind")})
    return rows


def table(rows) -> str:
    a = rows[0]
    lines = ["| defocus model | CPU s / sample | wall s / sample | CPU vs blur | band: bias RMS / p99 (f=48 periods) "
             "| band: wrong order % | band: corr. with reference | interior: bias RMS | interior: wrong % "
             "| label check effects (interior / edge) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ck = r["check"][0][1]  # orientation v, MF 1 -> 48
        lines.append(f"| {r['variant']} | {r['cpu_s']:.2f} | {r['wall_s']:.2f} | {r['cpu_s'] / a['cpu_s']:.2f}x "
                     f"| {r['band']['rms']:.3f} / {r['band']['p99']:.3f} | {r['band']['wrong_pct']:.2f} "
                     f"| {r['band']['corr']:.3f} | {r['interior']['rms']:.4f} | {r['interior']['wrong_pct']:.3f} "
                     f"| {ck[2]} / {ck[3]} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, help="folder for the configs and exports")
    ap.add_argument("--samples", type=int, default=4)
    ap.add_argument("--points", type=int, nargs="*", default=[8, 16, 32])
    ap.add_argument("--seed", type=int, default=2121)
    ap.add_argument("--band", type=int, default=8, help="outline band half-width, px")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--config", type=Path, default=None,
                    help="instead: the cost of one sample (--index) of this export config with the blur and "
                         "with --points aperture points on both devices")
    ap.add_argument("--index", type=int, default=0)
    ap.add_argument("--exact", action="store_true",
                    help="with --config: also the thin lens with the interreflection computed per aperture point")
    ap.add_argument("--quick", action="store_true", help="1 sample, blur vs 4 points (a temporary --work)")
    a = ap.parse_args(argv)
    load0 = os.getloadavg()[0]
    if a.config is not None:
        rows = config_cost(a.config, a.index, sorted(a.points), exact=a.exact)
        print(f"load {load0:.1f} -> {os.getloadavg()[0]:.1f}; {a.config} sample {a.index}")
        print("| defocus | CPU s | wall s | CPU vs blur | patterns s (wall) | models | interreflection "
              "| layout |")
        print("|---|---|---|---|---|---|---|---|")
        for r in rows:
            models = ", ".join(f"{k.split('_')[0]} {v['model']} ({v['max_disc_px']:.1f} px)"
                               for k, v in (r["defocus"] or {}).items()) or "blur"
            print(f"| {r['variant']} | {r['cpu_s']:.1f} | {r['wall_s']:.1f} | {r['cpu_s'] / rows[0]['cpu_s']:.2f}x "
                  f"| {r['stages'].get('patterns', 0):.1f} | {models} | {r['interreflection']} | {r['layout']} |")
        if a.json:
            from unwrap.safe_output import write_text

            write_text(a.json, json.dumps(rows, indent=1, default=str))
        return rows
    if a.quick:  # make bench: that it runs, not numbers to quote
        a.samples, a.points = 1, [4]
        if a.work is None:
            import tempfile

            a.work = Path(tempfile.mkdtemp(prefix="export_thin_lens_"))
    if a.work is None:
        ap.error("--work is required (or --config, or --quick)")
    rows = run(a.work, a.samples, sorted(a.points), a.seed, a.band)
    print(f"load {load0:.1f} -> {os.getloadavg()[0]:.1f}; {a.samples} samples a variant, band {a.band} px, "
          f"reference lens{max(a.points) if a.points else ''}")
    for r in rows:
        models = ", ".join(f"{k} x{v}" for k, v in r["models"].items()) or "-"
        print(f"{r['variant']}: same scenes as blur: {r['same_scenes']}; models (samples): {models}; "
              f"band pixels {r['band']['pixels']}, interior {r['interior']['pixels']}")
    print(table(rows))
    if a.json:
        from unwrap.safe_output import write_text

        write_text(a.json, json.dumps(rows, indent=1))
    return rows


if __name__ == "__main__":
    main()
