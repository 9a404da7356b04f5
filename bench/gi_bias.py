"""Interreflection bias of the unit-frequency phase, Blender Cycles against the twin:
``python -m bench.gi_bias [--quick] [--scenes ball-wall corner bunny-wall] [--samples 256]
[--seeds 2] [--fresh] [--repeats 3] [--figures out/gi_bias] [--write-reference PATH] [-q]``.

Scenes (experiments.gi_bias): a 25.4 mm ball 4.6 mm before a matte wall, a concave 90 degree corner,
the Stanford bunny 5 mm before the wall; albedo 0.8; the parity twin (ideal system, 160x120
camera), 8 steps of vertical fringes at f = 1. Per scene and renderer the bias map is
``wrap(phi_gi - phi_direct)``; Cycles renders with 4 diffuse bounces at ``--samples`` samples
per pixel with each of ``--seeds`` seeds (the reference is their circular mean; the RMS of two
seeds' difference / sqrt 2 is one map's noise) against its own 1-sample direct frames.

Rows: ours with synth.effects.interreflection (1 and 2 bounces, default patches; on mesh scenes also
without mesh visibility) and the old
screen-space term (synth.effects.global_illumination, ``interreflection`` 0.2 over 40 mm). Columns:
pixels compared, Cycles bias RMS / p99 and noise, correlation and RMS difference / bias RMS per
model, our time for the whole 8-frame stack (geometry included, minimum over ``--repeats``) and
Cycles' time for the same 8 frames (sum of its per-frame render times; from the cache unless
``--fresh``: then measured in this run), and their ratio. Cycles time is linear in samples
(docs/BLENDER-NOTES): the 64-sample column divides by ``samples / 64``. As an anchor measured in
the same run whatever the cache, one fresh Cycles frame at ``--anchor-samples`` (default 64,
the issue's setting) is rendered per scene and its time x 8 set against ours.

``--quick``: no Blender: the ball-wall scene against the stored test reference
(tests/data/gi_bias_ball_wall.npz), our timing only. ``--write-reference PATH`` writes the
ball-wall reference the tests use (needs the Cycles renders). Figures: one PNG per scene
(Cycles | ours | old term | Cycles - ours), written atomically to ``--figures``.

Cycles maps are cached in ``$SLTWIN_GI_CACHE`` (default: the temporary folder's
``sltwin_gi_cache``); a first full run renders 2 x 8 frames at 256 samples per scene (about
2-4 min a scene on 2 free cores).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from unwrap.safe_output import save_figure

REFERENCE = Path(__file__).resolve().parents[1] / "tests" / "data" / "gi_bias_ball_wall.npz"
OLD_TERM = {"interreflection": 0.2, "interreflection_mm": 40.0}


def _log(quiet, *a):
    if not quiet:
        print(*a, file=sys.stderr, flush=True)


def _ours(name, repeats):
    """Our bias maps (1 bounce, 2 bounces, old term), the geometry and our best stack time (s)."""
    from synth.effects.spec import GlobalIllumination, Interreflection
    from experiments.gi_bias import bias_map, ours_images

    direct, res = ours_images(name, None)
    best = float("inf")
    for _ in range(repeats):
        one, r1 = ours_images(name, Interreflection())
        best = min(best, r1.timings["total"])  # render() alone: geometry + every stage
    two, _ = ours_images(name, Interreflection(bounces=2))
    old, _ = ours_images(name, None, gi=GlobalIllumination(**OLD_TERM))
    plan = next(line for line in r1.plan if line.startswith("interreflection"))
    maps = {"ours 1 bounce": bias_map(one, direct), "ours 2 bounces": bias_map(two, direct),
            "old term": bias_map(old, direct)}
    extra = {}
    if any(o.kind == "mesh" for o in scene_objects(name)):
        mv, rm = ours_images(name, Interreflection(mesh_visibility=False))
        extra["ours 1 bounce, no mesh visibility"] = rm.timings["total"]
        maps["ours 1 bounce, no mesh visibility"] = bias_map(mv, direct)
    return {"direct": direct, "geometry": res.geometry, "seconds": best, "plan": plan, "maps": maps,
            "extra_seconds": extra}


def scene_objects(name):
    from experiments.gi_bias import bias_scene

    return bias_scene(name).objects


def _cycles_anchor(name, samples, threads) -> float:
    """Seconds of one fresh Cycles frame (4 bounces, ``samples``) of scene ``name``, this run."""
    from synth.blender_twin import render_in_blender
    from experiments.gi_bias import EXPOSURE, _setup, bias_scene

    system, d_ref, patterns = _setup(8)
    proj = patterns[0].projector_image(system.projector.size, 0.5, 0.5)[None]
    out = render_in_blender(system, bias_scene(name).meshes, proj, exposure=EXPOSURE, reference_distance_mm=d_ref,
                            threads=threads, samples=samples, bounces=4)
    return float(out["seconds_per_frame"][0])


def _figure(path, name, ref, maps, mask):
    panels = [("Cycles (4 bounces)", ref), ("ours, 1 bounce", maps["ours 1 bounce"]), ("old term", maps["old term"]),
              ("Cycles - ours", ref - maps["ours 1 bounce"])]
    bias_figure(path, panels, mask, float(np.percentile(np.abs(ref[mask]), 99)) or 1e-3,
                f"{name}: wrap(phi_gi - phi_direct) at f = 1 (x 64 / 2 pi = fringes of a 64-period pattern)")


def bias_figure(path, panels, mask, v, title):
    """Four bias maps (``panels``: (title, (H,W) rad)) side by side, colour range +-v, written atomically."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(16, 3.4))
    for ax, (label, m) in zip(axes, panels):
        im = ax.imshow(np.where(mask, m, np.nan), cmap="RdBu", vmin=-v, vmax=v)
        ax.set_title(label)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(im, ax=axes, shrink=0.8, label="unit-phase bias (rad)")
    fig.suptitle(title)
    try:
        save_figure(fig, path, dpi=80)
    finally:
        plt.close(fig)


def _timings(rows):
    """(scene, row label, our seconds, Cycles seconds, samples) for the default and extra rows."""
    for name, _, _, ours_s, cyc_s, samples, _, extra in rows:
        for label, sec in [("", ours_s)] + [(f" ({k})", v) for k, v in extra.items()]:
            yield name, label, sec, cyc_s, samples


def _print_tables(rows, anchor, a):
    """The Markdown tables of :func:`main`."""
    from experiments.gi_bias import FINE_PERIODS

    print(f"## Unit-phase interreflection bias, Cycles (4 bounces{', stored reference' if a.quick else ''}) vs ours\n")
    print("| scene | pixels | Cycles bias RMS / p99 (rad) | fringes (x64) p99 | Cycles noise / seed | model | correlation "
          "| RMS diff / bias RMS |")
    print("|---|---|---|---|---|---|---|---|")
    for name, cmp, noise, *_ in rows:
        c0 = cmp["ours 1 bounce"]
        for k, c in cmp.items():
            print(f"| {name} | {c0['pixels']} | {c0['bias_rms']:.4f} / {c0['bias_p99']:.3f} | "
                  f"{c0['bias_p99'] * FINE_PERIODS / (2 * np.pi):.2f} | {noise:.4f} | {k} | {c['correlation']:.3f} | "
                  f"{c['diff_over_bias']:.3f} |")
    print("\n## Time for the 8-frame stack (ours: geometry + every stage, 1 bounce; Cycles: its render times)\n")
    print("| scene | ours ms | Cycles s (samples) | speed-up | Cycles s at 64 samples (scaled) | speed-up at 64 |")
    print("|---|---|---|---|---|---|")
    for name, label, sec, cyc_s, samples in _timings(rows):
        if cyc_s is None:
            print(f"| {name}{label} | {sec * 1e3:.0f} | (not run: --quick) | | | |")
        else:
            c64 = cyc_s * 64 / samples
            print(f"| {name}{label} | {sec * 1e3:.0f} | {cyc_s:.1f} ({samples}) | {cyc_s / sec:.1f}x | {c64:.1f} | "
                  f"{c64 / sec:.1f}x |")
    if anchor:
        print(f"\nSame-run anchor: one fresh Cycles frame at {a.anchor_samples} samples x 8 frames, against our "
              "stack time above:\n")
        print("| scene | Cycles s (8 x 1 frame, this run) | speed-up (ours 1 bounce) |")
        print("|---|---|---|")
        for name, label, sec, _, _ in _timings(rows):
            if name in anchor:
                print(f"| {name}{label} | {anchor[name]:.1f} | {anchor[name] / sec:.0f}x |")
    print()
    for name, *_, plan, _ in rows:
        print(f"- {name}: {plan}")
    if a.figures:
        print(f"\nFigures: {a.figures}/<scene>.png")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.gi_bias", description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="no Blender: ball-wall against the stored test reference")
    ap.add_argument("--scenes", nargs="+", default=["ball-wall", "corner", "bunny-wall"])
    ap.add_argument("--samples", type=int, default=256)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--fresh", action="store_true", help="render Cycles again (no cache): its time is this run's")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2, help="Cycles threads")
    ap.add_argument("--anchor-samples", type=int, default=64,
                    help="also time one fresh Cycles frame at this many samples in this run (0: no)")
    ap.add_argument("--figures", type=Path, default=Path("out/gi_bias"))
    ap.add_argument("--write-reference", type=Path, default=None)
    ap.add_argument("-q", "--quiet", action="store_true")
    a = ap.parse_args(argv)
    from experiments.gi_bias import compare, comparison_mask, cycles_bias, load_reference, save_reference

    scenes = ["ball-wall"] if a.quick else a.scenes
    rows = []
    anchor = {}
    for name in scenes:
        _log(a.quiet, f"[gi_bias] {name}: ours")
        ours = _ours(name, 1 if a.quick else a.repeats)
        if a.quick:
            ref, mask, meta = load_reference(REFERENCE)
            noise, cyc_s, samples = float(meta["noise_rms_per_seed"]), None, int(meta["samples"])
        else:
            _log(a.quiet, f"[gi_bias] {name}: Cycles ({a.samples} samples x {a.seeds} seeds, cache {'off' if a.fresh else 'on'})")
            if a.fresh:
                os.environ["SLTWIN_GI_CACHE"] = str(Path(os.environ.get("TMPDIR", "/tmp")) / f"sltwin_gi_fresh_{os.getpid()}")
            c = cycles_bias(name, samples=a.samples, seeds=tuple(range(a.seeds)), threads=a.threads)
            ref = c["bias"]
            mask = comparison_mask(ours["geometry"], c["direct"], ours["direct"])
            noise = (float(np.sqrt(np.mean((c["maps"][0] - c["maps"][1])[mask] ** 2)) / np.sqrt(2))
                     if len(c["maps"]) > 1 else float("nan"))
            cyc_s, samples = float(np.sum(c["seconds_per_frame"])) / len(c["maps"]), a.samples
            if a.anchor_samples:
                anchor[name] = 8 * _cycles_anchor(name, a.anchor_samples, a.threads)
            if a.write_reference and name == "ball-wall":
                save_reference(a.write_reference, name, ref, mask, {"samples": a.samples, "bounces": 4,
                                                                   "seeds": a.seeds, "noise_rms_per_seed": noise,
                                                                   "steps": 8})
                _log(a.quiet, f"[gi_bias] wrote {a.write_reference}")
        cmp = {k: compare(ref, m, mask) for k, m in ours["maps"].items()}
        rows.append((name, cmp, noise, ours["seconds"], cyc_s, samples, ours["plan"], ours["extra_seconds"]))
        if a.figures:
            _figure(a.figures / f"{name}.png", name, ref, ours["maps"], mask)

    _print_tables(rows, anchor, a)
    return 0


if __name__ == "__main__":
    sys.exit(main())
