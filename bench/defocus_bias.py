"""Camera defocus and response curves against Blender Cycles on the unit-phase bias:
``python -m bench.defocus_bias [--quick] [--samples 256] [--seeds 2] [--lens-samples 16 32]
[--repeats 3] [--figures out/defocus_bias] [--write-reference PATH] [-q]``.

Scene (experiments.defocus_bias): a 25.4 mm ball 34.6 mm before a matte wall, the parity twin
(160x120), 8 steps of vertical fringes at f = 1, a thin lens of 80 mm aperture focused on the
ball (822.2 mm: the wall blurs ~6 px) or on the wall (906.9 mm: the ball blurs ~6 px). Per
renderer the bias is ``wrap(phi_defocused - phi_pinhole)``; Cycles: depth of field, direct light,
``--samples`` per pixel, ``--seeds`` seeds (reference: their circular mean; noise: RMS of two
seeds' difference / sqrt 2), against its 1-sample pinhole frames. Ours: the thin lens
(synth.effects.thin_lens) at each ``--lens-samples`` and the old blur of the finished image.
Two masks: all compared pixels (experiments.gi_bias.comparison_mask) and the outline band (those
within 8 px of another object's pixel or of a shadow's edge, where defocus mixes light of
another projector column or a one-sided disc).

Response curves (synth.effects.response, projector_gamma): the projector's gamma 2.2 / 0.6 at 4
and 8 steps (Cycles: the pattern images raised to gamma; 1-sample point-sampled direct light,
deterministic), bias ``wrap(phi_gamma - phi_linear)``; the camera's curve 1/2.2 after the lens
(Cycles: its depth-of-field frames through the same curve, as a colour-management curve would),
bias ``wrap(phi_lens,curve - phi_pinhole,linear)``: the curve's harmonics and the lens together.

Projector defocus (synth.effects.thin_lens, projector_defocus.samples) cannot be rendered by
Cycles (the twin's textured spot light breaks with any radius: ../shared/docs/BLENDER-NOTES.md);
it is checked against an independent brute-force aperture integral instead
(experiments.defocus_bias.projector_reference_bias).

``--subsurface``: also Cycles' random-walk subsurface scattering (weight 0.8, radius 4 mm, on
the ball-wall scene of experiments.gi_bias, 4 bounces) against our screen-space subsurface term
(experiments.subsurface_bias); ``--skip-defocus`` prints only that table.

Times: ours, ``render()`` of the 8-frame stack, minimum over ``--repeats``; Cycles: the sum of
its render times of one seed's 8 frames (cached from the run that rendered them).
``--quick``: no Blender, the stored test reference (tests/data/defocus_bias_ball_wall.npz).
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

REFERENCE = Path(__file__).resolve().parents[1] / "tests" / "data" / "defocus_bias_ball_wall.npz"
FOCI = {"ball-wall-dof, focus on the ball": 822.2, "ball-wall-dof, focus on the wall": 906.9}
CAMERA_CURVE = 1 / 2.2


def _log(quiet, *a):
    if not quiet:
        print(*a, file=sys.stderr, flush=True)


def _best_time(fn, repeats):
    best, out = float("inf"), None
    for _ in range(repeats):
        out = fn()
        best = min(best, out["seconds"])
    return best, out


def _figure(path, title, ref, maps, mask):
    from .gi_bias import bias_figure

    first = next(iter(maps))
    panels = [("Cycles", ref)] + list(maps.items())[:2] + [(f"Cycles - {first}", ref - maps[first])]
    bias_figure(path, panels, mask, float(np.percentile(np.abs(ref[mask]), 99.5)) or 1e-3, title)


def _defocus_rows(a, name, focus):
    from experiments.defocus_bias import APERTURE_MM, cycles_dof_bias, ours_dof_bias
    from experiments.defocus_bias import outline_band
    from experiments.gi_bias import compare, comparison_mask

    ours = {}
    times = {}
    for S in a.lens_samples:
        times[f"thin lens, {S} points"], ours[f"thin lens, {S} points"] = _best_time(
            lambda: ours_dof_bias(samples=S, focus_mm=focus), a.repeats)
    times["old image blur"], ours["old image blur"] = _best_time(lambda: ours_dof_bias(samples=0, focus_mm=focus), a.repeats)
    g = next(iter(ours.values()))
    c = cycles_dof_bias(samples=a.samples, seeds=tuple(range(a.seeds)), aperture_mm=APERTURE_MM, focus_mm=focus)
    mask = comparison_mask(g["geometry"], c["direct"], g["direct"])
    band = mask & outline_band(g["geometry"])
    rows = []
    for m_name, m in (("all", mask), ("outline band", band)):
        noise = (float(np.sqrt(np.mean((c["maps"][0] - c["maps"][1])[m] ** 2)) / np.sqrt(2))
                 if len(c["maps"]) > 1 else float("nan"))
        for k, o in ours.items():
            rows.append((name, m_name, k, compare(c["bias"], o["bias"], m), noise, times[k],
                         float(np.sum(c["seconds_per_frame"])) / len(c["maps"])))
    if a.figures:
        _figure(a.figures / f"defocus_bias_focus_{'ball' if focus < 850 else 'wall'}.png",
                f"{name}: wrap(phi_lens - phi_pinhole) at f = 1",
                c["bias"], {k: o["bias"] for k, o in ours.items() if k != f"thin lens, {a.lens_samples[0]} points"}, mask)
    return rows, c, mask, ours


def _response_rows(a):
    from experiments.defocus_bias import APERTURE_MM, FOCUS_MM, cycles_dof_images, ours_dof_images
    from experiments.gi_bias import bias_map, compare, comparison_mask, wrap
    from synth.effects.spec import Defocus

    rows = []
    for n in (4, 8):
        lin_c = cycles_dof_images("ball-wall-dof", samples=1, aperture_mm=None, steps=n)
        lin_o, r0 = ours_dof_images("ball-wall-dof", None, steps=n)
        mask = comparison_mask(r0.geometry, lin_c["images"], lin_o)
        for gam in (2.2, 0.6):
            cg = cycles_dof_images("ball-wall-dof", samples=1, aperture_mm=None, steps=n, projector_gamma=gam)
            best = float("inf")
            for _ in range(a.repeats):
                og, rg = ours_dof_images("ball-wall-dof", None, steps=n, projector_gamma=gam)
                best = min(best, rg.timings["total"])
            rows.append(("ball-wall-dof, pinhole", f"projector gamma {gam}, {n} steps",
                         compare(bias_map(cg["images"], lin_c["images"]), bias_map(og, lin_o), mask), 0.0, best,
                         float(np.sum(cg["seconds_per_frame"]))))
    # the camera's curve after the lens: Cycles' depth-of-field frames through the curve
    pin_c = cycles_dof_images("ball-wall-dof", samples=1, aperture_mm=None, steps=8)["images"]
    maps = []
    secs = []
    for s in range(a.seeds):
        cd = cycles_dof_images("ball-wall-dof", samples=a.samples, aperture_mm=APERTURE_MM, focus_mm=FOCUS_MM, seed=s)
        maps.append(bias_map(cd["images"] ** CAMERA_CURVE, pin_c))
        secs.append(float(np.sum(cd["seconds_per_frame"])))
    ref = wrap(np.angle(np.mean(np.exp(1j * np.stack(maps)), 0)))
    pin_o, r0 = ours_dof_images("ball-wall-dof", None)
    mask = comparison_mask(r0.geometry, pin_c, pin_o)
    noise = float(np.sqrt(np.mean((maps[0] - maps[1])[mask] ** 2)) / np.sqrt(2)) if len(maps) > 1 else float("nan")
    S = a.lens_samples[-1]
    best = float("inf")
    for _ in range(a.repeats):
        lo, rl = ours_dof_images("ball-wall-dof", Defocus(APERTURE_MM, FOCUS_MM, 6, S), camera_gamma=CAMERA_CURVE)
        best = min(best, rl.timings["total"])
    rows.append(("ball-wall-dof, focus on the ball", f"camera curve v^(1/2.2) after a {S}-point thin lens",
                 compare(ref, bias_map(lo, pin_o), mask), noise, best, float(np.mean(secs))))
    return rows


def _projector_rows(a):
    """The projector's thin lens (focused on the ball's front, 40 mm aperture) against the
    brute-force aperture integral of experiments.defocus_bias.projector_reference_bias."""
    import time

    from experiments.defocus_bias import PROJECTOR_FOCUS_MM, ours_dof_images, outline_band, projector_reference_bias
    from experiments.gi_bias import _setup, bias_map, compare, comparison_mask
    from synth.effects.spec import Defocus

    system, _, _ = _setup(8)
    pin, r0 = ours_dof_images("ball-wall-dof", None)
    t = time.perf_counter()
    ref = projector_reference_bias(r0.geometry, system, aperture_mm=40.0, focus_mm=PROJECTOR_FOCUS_MM)
    ref_s = time.perf_counter() - t
    m = comparison_mask(r0.geometry, pin, pin) & np.isfinite(ref)
    band = m & outline_band(r0.geometry)
    rows = []
    for S in a.lens_samples + [0]:
        best = float("inf")
        for _ in range(a.repeats):
            o, r = ours_dof_images("ball-wall-dof", None, projector_defocus=Defocus(40.0, PROJECTOR_FOCUS_MM, 6, S))
            best = min(best, r.timings["total"])
        for m_name, mm in (("all", m), ("outline band", band)):
            rows.append(("old pattern blur" if S == 0 else f"thin lens, {S} points", m_name,
                         compare(ref, bias_map(o, pin), mm), best, ref_s))
    return rows


def _subsurface_rows(a):
    """Cycles' random-walk subsurface against our screen-space term (experiments.subsurface_bias)."""
    from experiments.gi_bias import compare, comparison_mask
    from experiments.subsurface_bias import cycles_sss_bias, ours_sss_bias

    c = cycles_sss_bias(samples=a.samples, seeds=tuple(range(a.seeds)))
    o = ours_sss_bias()
    mask = comparison_mask(o["geometry"], c["direct"], o["direct"])
    noise = (float(np.sqrt(np.mean((c["maps"][0] - c["maps"][1])[mask] ** 2)) / np.sqrt(2))
             if len(c["maps"]) > 1 else float("nan"))
    return [("ball-wall, plaster-like (weight 0.8, radius 4 mm)", "screen-space subsurface (sigma 0.78 mm)",
             compare(c["bias"], o["bias"], mask), noise, o["seconds"],
             float(np.sum(c["seconds_per_frame"])) / len(c["maps"]))]


def _print_subsurface(a):
    _log(a.quiet, "[defocus_bias] subsurface scattering")
    _print_effect_rows("Subsurface scattering: unit-phase bias, Cycles random walk vs ours", _subsurface_rows(a))
    print()


def _print_effect_rows(heading, rows):
    """One Markdown table of (scene, effect, comparison, Cycles noise, our s, Cycles s) rows."""
    print(f"## {heading}\n")
    print("| scene | effect | pixels | Cycles bias RMS / p99 rad | Cycles noise / seed | correlation | "
          "RMS diff / bias RMS | ours ms | Cycles s | speed-up |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, k, c, noise, ours_s, cyc_s in rows:
        print(f"| {name} | {k} | {c['pixels']} | {c['bias_rms']:.2e} / {c['bias_p99']:.2e} | {noise:.1e} | "
              f"{c['correlation']:.4f} | {c['diff_over_bias']:.2e} | {ours_s * 1e3:.0f} | {cyc_s:.1f} | "
              f"{cyc_s / ours_s:.0f}x |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.defocus_bias", description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="no Blender: the stored test reference")
    ap.add_argument("--samples", type=int, default=256)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--lens-samples", type=int, nargs="+", default=[16, 32])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--figures", type=Path, default=Path("out/defocus_bias"))
    ap.add_argument("--write-reference", type=Path, default=None)
    ap.add_argument("--subsurface", action="store_true",
                    help="also Cycles' random-walk subsurface against our screen-space term (slow renders)")
    ap.add_argument("--skip-defocus", action="store_true", help="with --subsurface: only the subsurface rows")
    ap.add_argument("-q", "--quiet", action="store_true")
    a = ap.parse_args(argv)
    from experiments.defocus_bias import FOCUS_MM, ours_dof_bias
    from experiments.gi_bias import compare, load_reference, save_reference

    if a.quick:
        ref, mask, meta = load_reference(REFERENCE)
        print("| scene | model | correlation | RMS diff / bias RMS | ours ms |\n|---|---|---|---|---|")
        for S in a.lens_samples + [0]:
            o = ours_dof_bias(samples=S, focus_mm=float(meta["focus_mm"]))
            c = compare(ref, o["bias"], mask)
            print(f"| ball-wall-dof, focus on the ball (stored Cycles reference) | "
                  f"{'old image blur' if S == 0 else f'thin lens, {S} points'} | {c['correlation']:.3f} | "
                  f"{c['diff_over_bias']:.3f} | {o['seconds'] * 1e3:.0f} |")
        return 0
    if a.subsurface:
        _print_subsurface(a)
        if a.skip_defocus:
            return 0
    rows = []
    for name, focus in FOCI.items():
        _log(a.quiet, f"[defocus_bias] {name}")
        r, c, mask, _ = _defocus_rows(a, name, focus)
        rows += r
        if a.write_reference and focus == FOCUS_MM:
            save_reference(a.write_reference, "ball-wall-dof", c["bias"], mask,
                           {"samples": a.samples, "seeds": a.seeds, "focus_mm": focus, "steps": 8,
                            "noise_rms_per_seed": r[0][4]})
            _log(a.quiet, f"[defocus_bias] wrote {a.write_reference}")
    print("## Camera defocus: unit-phase bias, Cycles depth of field vs ours\n")
    print("| scene | pixels (mask) | Cycles bias RMS / p99 rad | Cycles noise / seed | model | correlation | "
          "RMS diff / bias RMS | ours ms | Cycles s (8 frames) | speed-up |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, m, k, c, noise, ours_s, cyc_s in rows:
        print(f"| {name} | {c['pixels']} ({m}) | {c['bias_rms']:.4f} / {c['bias_p99']:.3f} | {noise:.1e} | {k} | "
              f"{c['correlation']:.3f} | {c['diff_over_bias']:.3f} | {ours_s * 1e3:.0f} | {cyc_s:.1f} | "
              f"{cyc_s / ours_s:.0f}x |")
    _log(a.quiet, "[defocus_bias] projector defocus against the brute-force aperture integral")
    print("\n## Projector defocus (focus on the ball, 40 mm aperture): ours vs a brute-force aperture integral "
          "(24 x 48 points; Cycles cannot: BLENDER-NOTES)\n")
    print("| model | pixels (mask) | reference bias RMS / p99 rad | correlation | RMS diff / bias RMS | ours ms "
          "| reference s |")
    print("|---|---|---|---|---|---|---|")
    for k, m_name, c, ours_s, ref_s in _projector_rows(a):
        print(f"| {k} | {c['pixels']} ({m_name}) | {c['bias_rms']:.2e} / {c['bias_p99']:.2e} | {c['correlation']:.3f} | "
              f"{c['diff_over_bias']:.3f} | {ours_s * 1e3:.0f} | {ref_s:.1f} |")
    _log(a.quiet, "[defocus_bias] response curves")
    print()
    _print_effect_rows("Response curves: unit-phase bias, Cycles vs ours", _response_rows(a))
    return 0


if __name__ == "__main__":
    sys.exit(main())
