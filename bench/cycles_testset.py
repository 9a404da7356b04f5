"""The Cycles test set (issue 21, item 3): build it, then score every decoder on it.

    python -m bench.cycles_testset [--out DIR] [--size 320 240] [--samples 64] [--unit-seeds 4]
                                   [--scenes ...] [--eval-only FILE] [--json OUT.json] [--no-learned] [--quick]

Builds ``DIR/cycles_test.h5`` with :func:`experiments.cycles_testset.build_testset` (Blender
Cycles, 4 diffuse bounces; the Cycles frames are cached in ``DIR/frames``, so a rerun or an
interrupted run only renders what is missing; ~60 min on 2 shared cores at the defaults) and a
``DIR/README.txt`` saying how it was made; then, at f = 48 and f = 96 (MF pairs 1 -> f), the rows
of ``bench.spatial_unwrap`` on the same pixels - traditional, filtered 15x15, graph cut
(:mod:`unwrap.spatial_orders`), the shipped learned model, learned + graph cut, and their gated
variants - pooled over the scenes, and the bias statistics of the set: Cycles' unit-phase bias
(interreflection against its own direct light) against its sampling noise, the traditional errors
within 25 px of an invalid pixel (the bust: 93 %), in connected patches of >= 100 px, and the
label check (traditional MF on Cycles' noise-free direct frames against the twin's orders).

Default ``--out``: ``$SLTWIN_CYCLES_TESTSET`` or ``<tmp>/sltwin_cycles_testset`` (never the
repository). The rows are also what ``calib eval --cycles DIR/cycles_test.h5`` reports (MF rows).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from experiments.cycles_testset import SCENES
from unwrap.safe_output import write_text

README = """Cycles test set of sltwin (issue 21, item 3): held-out meshes rendered by Blender Cycles.

Rebuild (from the repository root; renders only the frames missing from ./frames):
    PYTHONPATH=$PWD nice -n 10 .venv/bin/python -m bench.cycles_testset --out {out} \\
        --size {w} {h} --samples {samples} --unit-seeds {nseeds}

File: cycles_test.h5 (dataset schema of docs/dataset.md, kind twin, v fringes, f = 1, 48, 96, 12 steps);
one sample per scene: {scenes}.
Made by: experiments.cycles_testset.build_testset, code {code}, {date}.
Camera: the default system made ideal, its 640x480 camera cropped to {w}x{h} at the full focal length.
Cycles: {samples} samples per pixel, 4 diffuse bounces, point-sampled pixels, seed 0; the unit frequency's
basis frames averaged over seeds 0..{nseeds_1} (their difference measures Cycles' noise).
Stacks: 12 steps synthesised from 3 basis frames per frequency (light transport is linear; see
experiments/cycles_testset.py).
Sensor (the twin's): Poisson-Gaussian, full well {fw:g} e-, read noise {rn:g} e-, 8 bits, noise seed = scene index.
Per-scene parameters and bias statistics: the 'params' dataset (JSON) of each sample.
frames/: the cached Cycles basis frames (.npz), keyed by scene, camera and settings.
"""


def default_out() -> Path:
    return Path(os.environ.get("SLTWIN_CYCLES_TESTSET", Path(tempfile.gettempdir()) / "sltwin_cycles_testset"))


def file_items(path, f: float):
    """Items of ``bench.spatial_unwrap`` for the MF pair (1, f) of every sample of the file, with
    the scene name and the sample's parameters."""
    import h5py

    from experiments.learned_parity import capture_noise
    from unwrap.dataset import FringeOrderDataset

    pair = (1.0, float(f))
    with h5py.File(path, "r") as h5:
        params = [json.loads(p) for p in h5["params"][:]]
        width = float(json.loads(h5.attrs["widths"])["v"])
    noise = capture_noise(path, "v", pair)
    ds = FringeOrderDataset(path, method="mf", frequencies=pair, orientation="v", crop=None, seed=0)
    maps = {"phase_low": "phase_low", "phase_high": "phase_high", "m_low": "modulation_low", "m_high": "modulation_high"}
    items = []
    for i in range(len(ds)):
        it = ds[i]
        item = {k: it[v][0].numpy().astype(np.float64) for k, v in maps.items()}
        item.update(name=f"Cycles set, f = {f:g} #{i}", scene=params[i].get("scene", {}).get("scene", str(i)),
                    params=params[i], valid=it["valid"].numpy(), ref=it["order_true"].numpy().astype(np.int64),
                    freqs=pair, width=width, steps=noise["steps"], sigma_I=noise["sigma_I"])
        items.append(item)
    return items


def error_context(items, radius: int = 25) -> dict:
    """Where the traditional errors sit (pooled over the items): share of the wrong pixels within
    ``radius`` px of an invalid pixel vs the share of the counted pixels there, share in connected
    patches of >= 100 px; and per scene the traditional error %."""
    from experiments.cycles_testset import wrong_pixel_context
    from unwrap.temporal import decode_pair

    tot = {"wrong": 0, "wrong_near": 0, "counted": 0, "counted_near": 0, "wrong_in_patches": 0}
    per_scene = {}
    for it in items:
        _, n, ok = decode_pair("mf", it["phase_low"], it["phase_high"], *it["freqs"], it["width"], it["valid"])
        m = ok & (it["ref"] >= 0)
        c = wrong_pixel_context(n != it["ref"], m, radius=radius)
        for k in tot:
            tot[k] += c[k]
        per_scene[it["scene"]] = 100.0 * c["wrong"] / max(c["counted"], 1)
    return {"wrong_near_invalid": tot["wrong_near"] / max(tot["wrong"], 1),
            "counted_near_invalid": tot["counted_near"] / max(tot["counted"], 1),
            "wrong_in_patches_100": tot["wrong_in_patches"] / max(tot["wrong"], 1),
            "traditional_per_scene_pct": per_scene, **tot}


def bias_table(items48, contexts: dict) -> str:
    """The bias statistics of the set (per scene) and where the traditional errors sit (per f)."""
    L = ["| scene | counted px | bias RMS rad | bias p99 rad (x48 fringes) | Cycles noise per seed / of the unit used, "
         "RMS rad | bias / noise of the unit | lit twin = lit Cycles (interior) | label check 48 / 96 (interior, edge) |",
         "|---|---:|---:|---:|---:|---:|---:|---|"]
    for it in items48:
        b = dict(it["params"].get("bias", {}))
        lc = it["params"].get("label_check_clean", {})
        rms, p99 = b.get("bias_rms_rad", np.nan), b.get("bias_p99_rad", np.nan)
        n1, nu = b.get("cycles_noise_rms_rad", np.nan), b.get("unit_noise_rms_rad", np.nan)
        counted = int((it["valid"] & (it["ref"] >= 0)).sum())
        L.append(f"| {it['scene']} | {counted:,} | {rms:.4f} | {p99:.3f} ({48 * p99 / (2 * np.pi):.2f}) | "
                 f"{n1:.4f} / {nu:.4f} | {rms / nu:.1f} | {100 * b.get('lit_agreement_interior', np.nan):.2f} % | "
                 f"{lc.get('48', '-')} / {lc.get('96', '-')} |")
    L += ["", "| scene | traditional % (no sensor noise) at 48: one seed's unit / the unit used / extrapolated to no "
              "Cycles noise | at 96 |", "|---|---|---|"]
    for it in items48:
        e = it["params"].get("bias", {}).get("error_vs_cycles_noise", {})
        cell = {f: " / ".join(f"{100 * v:.2f}" for v in (e[f][0], e[f][2], e[f][3])) if f in e else "-"
                for f in ("48", "96")}
        L.append(f"| {it['scene']} | {cell['48']} | {cell['96']} |")
    L += ["", "| f | traditional wrong px | within 25 px of an invalid px (counted px there) | in patches >= 100 px "
              "| traditional % per scene |", "|---|---:|---:|---:|---|"]
    for f, c in contexts.items():
        per = ", ".join(f"{k} {v:.2f}" for k, v in c["traditional_per_scene_pct"].items())
        L.append(f"| {f:g} | {c['wrong']:,} | {100 * c['wrong_near_invalid']:.1f} % "
                 f"({100 * c['counted_near_invalid']:.1f} %) | {100 * c['wrong_in_patches_100']:.1f} % | {per} |")
    return "\n".join(L)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.cycles_testset", description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=None, help="folder of the set and its frame cache (default: "
                                                "$SLTWIN_CYCLES_TESTSET or <tmp>/sltwin_cycles_testset)")
    ap.add_argument("--size", type=int, nargs=2, default=(320, 240), metavar=("W", "H"))
    ap.add_argument("--samples", type=int, default=64, help="Cycles samples per pixel (default 64)")
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--unit-seeds", type=int, default=4, help="seeds averaged for the unit frequency (>= 2 measures "
                                                               "Cycles' noise; default 4)")
    ap.add_argument("--eval-only", default=None, metavar="FILE", help="score an existing file, render nothing")
    ap.add_argument("--no-learned", action="store_true", help="skip the network rows")
    ap.add_argument("--json", default=None)
    ap.add_argument("--quick", action="store_true", help="a 64x48 crop, 4 samples, suzanne-wall only, in <out>/quick "
                                                         "(checks that the pipeline runs; numbers not for quoting)")
    args = ap.parse_args(argv)
    if args.quick:
        args.size, args.samples, args.scenes = (64, 48), 4, ["suzanne-wall"]
        args.out = str(Path(args.out or default_out()) / "quick")

    if args.eval_only:
        path = Path(args.eval_only)
    else:
        from experiments.cycles_testset import FULL_WELL_E, READ_NOISE_E, build_testset
        from synth.export.dataset import code_version

        out = Path(args.out) if args.out else default_out()
        out.mkdir(parents=True, exist_ok=True)
        path = out / "cycles_test.h5"
        t0 = time.perf_counter()

        def progress(name, s):
            print(f"{time.strftime('%H:%M:%S')} {name}: bias RMS {s['bias_rms_rad']:.4f} rad, Cycles noise "
                  f"{s.get('cycles_noise_rms_rad', float('nan')):.4f} rad", file=sys.stderr, flush=True)

        build_testset(path, scenes=tuple(args.scenes), size=tuple(args.size), samples=args.samples,
                      threads=args.threads, cache_dir=out, unit_seeds=tuple(range(args.unit_seeds)),
                      progress=progress)
        write_text(out / "README.txt", README.format(out=out, w=args.size[0], h=args.size[1], samples=args.samples,
                                     scenes=", ".join(args.scenes), nseeds=args.unit_seeds, code=code_version(),
                                     date=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), fw=FULL_WELL_E,
                                     rn=READ_NOISE_E, nseeds_1=args.unit_seeds - 1))
        print(f"{path}: built in {time.perf_counter() - t0:.0f} s", file=sys.stderr)

    from bench.spatial_unwrap import score, table
    from unwrap.spatial_orders import DEFAULTS, GATE

    params, gates = dict(DEFAULTS), {k: dict(v) for k, v in GATE.items()}
    results, contexts, items48 = {}, {}, None
    for f in (48.0, 96.0):
        items = file_items(path, f)
        if f == 48.0:
            items48 = items
        contexts[f] = error_context(items)
        res = score(items, params, gates, learned=not args.no_learned)
        results.update(res)
        print(table(res), flush=True)
    print("\n### Bias of the set (unit phase, Cycles 4 bounces vs Cycles direct; lit, non-edge pixels)\n")
    print(bias_table(items48, contexts))
    if args.json:
        write_text(Path(args.json), json.dumps({"file": str(path), "params": params, "gate": gates, "contexts": {
            str(k): v for k, v in contexts.items()}, "results": {
            k: {"rows": v["rows"], "curves": v["curves"], "ms": {r: float(np.median(m)) for r, m in v["ms"].items()},
                "pixels": v["pixels"]} for k, v in results.items()}}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
