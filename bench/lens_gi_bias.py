"""The camera's thin lens and the interreflection together against Blender Cycles, on the
unit-phase bias: ``python -m bench.lens_gi_bias [--quick] [--work DIR] [--scenes ball-wall-lens
suzanne-wall-lens] [--samples 512 256] [--seeds 2] [--repeats 2] [--anchor-samples 64]
[--figures out/lens_gi_bias] [--write-reference PATH] [-q]``.

Scenes (experiments.lens_gi_bias): the 25.4 mm ball 4.6 mm before a matte wall and the held-out
Suzanne mesh (80 mm) 5 mm before it, albedo 0.8, the parity twin (160x120), 8 steps of vertical
fringes at f = 1, the camera focused on the object's front with an 80 mm aperture. Per renderer
the bias is ``wrap(phi_lens+gi - phi_pinhole,direct)``. Cycles: depth of field and 4 diffuse
bounces, ``--samples`` per pixel (one value per scene, or one for all), ``--seeds`` seeds
(reference: circular mean; noise per seed: RMS of two seeds' difference / sqrt 2), against its
1-sample pinhole direct frames. Ours (experiments.lens_gi_bias.MODELS): the 32-point thin lens
with the 1-bounce interreflection shared between the aperture points (the default) or computed
per point (``exact``), the old blur of the finished image with the interreflection, and each
effect alone. Masks: all compared pixels (experiments.gi_bias.comparison_mask) and the outline
band (within 8 px of another object or a shadow's edge, experiments.defocus_bias.outline_band).

Times: ours, ``render()`` of the 8-frame stack (geometry and every stage), for the headline model
(thin lens + shared interreflection) the minimum over ``--repeats``, for the others one render,
after a warm-up render (numba compiles on the first); Cycles: the sum of its
render times of one seed's 8 frames (from the run that rendered and cached them under
``--work``), and, as an anchor measured in this run, one fresh frame at ``--anchor-samples`` x 8.

``--quick``: no Blender: ball-wall-lens against the stored test reference
(tests/data/lens_gi_bias_ball_wall.npz, written by ``--write-reference``), three of the models.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

REFERENCE = Path(__file__).resolve().parents[1] / "tests" / "data" / "lens_gi_bias_ball_wall.npz"
HEADLINE = "thin lens + interreflection, shared"
#: the models of ``--quick`` (the exact path's 32 transports are left to the full run)
QUICK_MODELS = (HEADLINE, "old image blur + interreflection", "thin lens alone (no interreflection)")


def _log(quiet, *a):
    if not quiet:
        print(*a, file=sys.stderr, flush=True)


def ours_models(name: str, repeats: int, models=None) -> dict:
    """{model: (bias map dict of experiments.lens_gi_bias.ours_lens_bias, seconds)}, after one
    warm-up render of the headline model; its seconds the minimum over ``repeats``, the other
    models' of one render."""
    from experiments.lens_gi_bias import MODELS, ours_lens_bias, ours_lens_images

    direct = ours_lens_images(name, None, None)
    ours_lens_images(name, *MODELS[HEADLINE])  # warm-up: numba's kernels compile on their first call
    out = {}
    for k in models or MODELS:
        best, o = float("inf"), None
        for _ in range(max(1, repeats if k == HEADLINE else 1)):
            o = ours_lens_bias(name, *MODELS[k], direct=direct)
            best = min(best, o["seconds"])
        out[k] = (o, best)
    return out


def _anchor(name: str, samples: int) -> float:
    """Seconds of one fresh Cycles frame (depth of field, 4 bounces, ``samples``), this run, x 8."""
    from experiments.defocus_bias import APERTURE_MM
    from experiments.lens_gi_bias import BOUNCES, cycles_lens_images

    o = cycles_lens_images(name, samples=samples, bounces=BOUNCES, aperture_mm=APERTURE_MM, frames=1)
    return 8 * float(o["seconds_per_frame"][0])


def _figure(path, name, ref, ours, mask):
    from .gi_bias import bias_figure

    sh, old = ours[HEADLINE][0]["bias"], ours["old image blur + interreflection"][0]["bias"]
    panels = [("Cycles (lens + 4 bounces)", ref), ("ours: thin lens + shared GI", sh),
              ("ours: old blur + GI", old), ("Cycles - ours (thin lens + shared)", ref - sh)]
    bias_figure(path, panels, mask, float(np.percentile(np.abs(ref[mask]), 99)) or 1e-3,
                f"{name}: wrap(phi_lens+gi - phi_pinhole,direct) at f = 1")


def _noise(c, m) -> float:
    if len(c["maps"]) < 2:
        return float("nan")
    return float(np.sqrt(np.mean((c["maps"][0] - c["maps"][1])[m] ** 2)) / np.sqrt(2))


def _quick(a) -> int:
    from experiments.defocus_bias import outline_band
    from experiments.gi_bias import compare, load_reference

    ref, mask, meta = load_reference(REFERENCE)
    ours = ours_models("ball-wall-lens", 1, QUICK_MODELS)
    band = mask & outline_band(next(iter(ours.values()))[0]["geometry"])
    print(f"## ball-wall-lens against the stored Cycles reference ({int(meta['samples'])} samples x "
          f"{int(meta['seeds'])} seeds, noise {float(meta['noise_rms_per_seed']):.4f} rad per seed)\n")
    print("| model | correlation (all / band) | RMS diff / bias RMS (all / band) | ours ms |\n|---|---|---|---|")
    for k, (o, sec) in ours.items():
        c, b = compare(ref, o["bias"], mask), compare(ref, o["bias"], band)
        print(f"| {k} | {c['correlation']:.3f} / {b['correlation']:.3f} | {c['diff_over_bias']:.3f} / "
              f"{b['diff_over_bias']:.3f} | {sec * 1e3:.0f} |")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.lens_gi_bias", description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="no Blender: ball-wall-lens against the stored reference")
    ap.add_argument("--work", type=Path, default=None,
                    help="Cycles cache folder (default $SLTWIN_GI_CACHE or the temporary folder's sltwin_gi_cache)")
    ap.add_argument("--scenes", nargs="+", default=["ball-wall-lens", "suzanne-wall-lens"])
    ap.add_argument("--samples", type=int, nargs="+", default=[512, 256], help="Cycles samples, one per scene")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--anchor-samples", type=int, default=64, help="one fresh Cycles frame at this many (0: none)")
    ap.add_argument("--figures", type=lambda v: Path(v) if v else None, default=Path("out/lens_gi_bias"),
                    help='folder of the figures ("": none)')
    ap.add_argument("--write-reference", type=Path, default=None)
    ap.add_argument("-q", "--quiet", action="store_true")
    a = ap.parse_args(argv)
    if a.quick:
        return _quick(a)
    if a.work is not None:
        a.work.mkdir(parents=True, exist_ok=True)
        os.environ["SLTWIN_GI_CACHE"] = str(a.work)
    from experiments.defocus_bias import outline_band
    from experiments.gi_bias import FINE_PERIODS, compare, comparison_mask, save_reference
    from experiments.lens_gi_bias import cycles_lens_bias, lens_scene

    samples = dict(zip(a.scenes, a.samples + [a.samples[-1]] * len(a.scenes)))
    rows, anchors, plans = [], {}, {}
    for name in a.scenes:
        _log(a.quiet, f"[lens_gi_bias] {name}: Cycles ({samples[name]} samples x {a.seeds} seeds, cache "
                      f"{os.environ.get('SLTWIN_GI_CACHE', 'default')})")
        c = cycles_lens_bias(name, samples=samples[name], seeds=tuple(range(a.seeds)))
        _log(a.quiet, f"[lens_gi_bias] {name}: ours")
        ours = ours_models(name, a.repeats)
        g = ours[HEADLINE][0]
        plans[name] = [line for line in g["plan"] if line.startswith(("interreflection", "camera defocus"))]
        mask = comparison_mask(g["geometry"], c["direct"], g["direct"])
        band = mask & outline_band(g["geometry"])
        cyc_s = float(np.sum(c["seconds_per_frame"])) / len(c["maps"])
        if a.anchor_samples:
            anchors[name] = _anchor(name, a.anchor_samples)
        for m_name, m in (("all", mask), ("outline band", band)):
            for k, (o, sec) in ours.items():
                rows.append((name, m_name, k, compare(c["bias"], o["bias"], m), _noise(c, m), sec, cyc_s,
                             samples[name]))
        if a.write_reference and name == "ball-wall-lens":
            save_reference(a.write_reference, name, c["bias"], mask,
                           {"samples": samples[name], "seeds": a.seeds, "bounces": 4, "steps": 8,
                            "focus_mm": lens_scene(name)[1], "aperture_mm": 80.0,
                            "noise_rms_per_seed": _noise(c, mask)})
            _log(a.quiet, f"[lens_gi_bias] wrote {a.write_reference}")
        if a.figures:
            _figure(a.figures / f"lens_gi_bias_{name}.png", name, c["bias"], ours, mask)

    print("## Thin lens + interreflection: unit-phase bias, Cycles (depth of field, 4 bounces) vs ours\n")
    print("| scene | pixels (mask) | Cycles bias RMS / p99 rad (p99 x64 fringes) | Cycles noise / seed | model | "
          "correlation | RMS diff / bias RMS | ours ms | Cycles s (8 frames, samples) | speed-up |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, m, k, c, noise, sec, cyc_s, s in rows:
        print(f"| {name} | {c['pixels']} ({m}) | {c['bias_rms']:.4f} / {c['bias_p99']:.3f} "
              f"({c['bias_p99'] * FINE_PERIODS / (2 * np.pi):.2f}) | {noise:.4f} | {k} | {c['correlation']:.3f} | "
              f"{c['diff_over_bias']:.3f} | {sec * 1e3:.0f} | {cyc_s:.1f} ({s}) | {cyc_s / sec:.0f}x |")
    if anchors:
        print(f"\nSame-run anchor: one fresh Cycles frame (depth of field, 4 bounces, {a.anchor_samples} samples) "
              "x 8, against our headline model's stack:\n")
        print("| scene | Cycles s (8 x 1 frame, this run) | ours ms | speed-up | at the reference's samples "
              "(Cycles time linear in samples) |\n|---|---|---|---|---|")
        for name, t in anchors.items():
            sec = next(r[5] for r in rows if r[0] == name and r[2] == HEADLINE)
            ref = t * samples[name] / a.anchor_samples
            print(f"| {name} | {t:.1f} | {sec * 1e3:.0f} | {t / sec:.0f}x | {ref:.0f} s ({samples[name]}): "
                  f"{ref / sec:.0f}x |")
    print()
    for name, lines in plans.items():
        for line in lines:
            print(f"- {name}: {line}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
