"""Twin vs real traditional error on SLStudio's skull (issue 21's goal: within 1.5x), with twins
built from what the capture measures.

    python -m bench.skull_parity [--work DIR] [--seeds 3] [--json OUT.json] [--quick]

Every twin is the pixel twin of :mod:`experiments.pixel_twin` (the capture's own background and
modulation per pixel, its geometry from the reference, the same labelled pixels and reference
rule, the sensor fitted on the capture, ``seeds`` noise draws), with the unit phase biased by:

- nothing (the sensor alone);
- the capture's own coherent unit-phase bias (``unit_phase_bias``, 15x15 box; 9x9 and 5x5 boxes
  leave-one-out), and the 5x5 map of a *twin* (noise only: what the small box's own noise adds);
- the physically based interreflection (``synth.effects.interreflection``) rendered on the
  capture's own geometry (:mod:`experiments.capture_gi`: albedo 0.8 and 1.0, one and two
  bounces), with its correlation to the measured bias; the last one also scaled to the measured
  bias's amplitude (a fit to the bias map, never to the error rate).

Rows: traditional MF 1 -> 16 error on the labelled pixels (% and count, mean over the seeds and
the range), real / twin. Renders and twins are cached in ``--work`` (~1 min per interreflection
render at half resolution, ``--scale 2 --stride 2``, the default; ~2-4 min at full, ``--scale 1``;
~15 s per twin; 2 shared cores). Needs ``../shared/data``.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from unwrap.safe_output import atomic_path, write_text

ROOT = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "slstudio-ps2x3-calib"
#: in the names of the cached renders and twins: bumped when what experiments.pixel_twin / capture_gi
#: write changes (p2: the plane without the 2 pi spikes of moved orders), so that an old --work is not reused
CACHE = "p2"


def _errors(path) -> tuple[int, int]:
    from unwrap.dataset import FringeOrderDataset

    it = FringeOrderDataset(path, method="mf", frequencies=(1.0, 16.0), orientation="v", crop=None, seed=0)[0]
    lab = it["order_true"] >= 0
    return int((it["order_traditional"][lab] != it["order_true"][lab]).sum()), int(lab.sum())


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name).strip("_")


def _interreflection_rows(real, system, work: Path, scale: int, stride: int) -> dict:
    """{row name: (bias (H, W) rad, note)} of the interreflection renders (cached in ``work``) and the
    last one scaled to the measured bias's amplitude."""
    from experiments.capture_gi import compare_bias, interreflection_bias
    from experiments.pixel_twin import unit_phase_bias

    biases = {}
    measured15 = unit_phase_bias(real, window=15)
    for albedo, bounces in ((0.8, 1), (0.8, 2), (1.0, 2)):
        cache = work / (f"gi_{CACHE}_a{albedo}_b{bounces}_x{scale}.npz" if stride == scale else
                        f"gi_{CACHE}_a{albedo}_b{bounces}_x{scale}_s{stride}.npz")
        if cache.exists():
            z = np.load(cache)
            r = {"bias": z["bias"], "lit": z["lit"], "seconds": float(z["seconds"])}
        else:
            r = interreflection_bias(real, system, stride=stride, scale=scale, albedo=albedo, bounces=bounces)
            with atomic_path(cache) as tmp:
                np.savez(tmp, bias=r["bias"], lit=r["lit"], seconds=r["seconds"])
        c = compare_bias(r["bias"], r["lit"], measured15, 15)
        biases[f"+ interreflection, albedo {albedo}, {bounces} bounce(s)"] = (
            r["bias"], f"corr {c['correlation']:.2f}, rendered rms {c['rms_rendered']:.4f} (x{c['scale']:.2f} = "
                       f"measured), {r['seconds']:.0f} s")
    # the last render with its amplitude scaled to the capture's measured bias (a fit to the bias map, not to
    # the error rate): what the missing indirect light (surfaces the camera does not see) would add
    biases[f"+ interreflection, albedo {albedo}, {bounces} bounces, x{c['scale']:.2f} (measured amplitude)"] = (
        r["bias"] * c["scale"], "amplitude fitted to the measured 15x15 bias map")
    return biases


def _print_table(rows, seeds: int, wrong_real: int, n_real: int) -> None:
    print(f"\n| twin (seeds {seeds}) | traditional % | wrong | real / twin | note |\n|---|---:|---:|---:|---|")
    print(f"| real capture | {100.0 * wrong_real / n_real:.3f} | {wrong_real} | 1 | {n_real} labelled pixels |")
    for r in rows:
        print(f"| {r['twin']} | {r['rate_pct']:.3f} | {min(r['wrong'])}-{max(r['wrong'])} | {r['real_over_twin']:.2f} | "
              f"{r['note']} |")


def main(argv=None) -> int:
    from experiments.pixel_twin import capture_sensor, pixel_twin, unit_phase_bias
    from synth.export.capture import export_capture

    ap = argparse.ArgumentParser(prog="python -m bench.skull_parity", description=__doc__.split("\n")[0])
    ap.add_argument("--work", default="/tmp/sltwin_skull_parity", help="cache of the export, renders and twins")
    ap.add_argument("--data", default=str(ROOT), help="the slstudio-ps2x3-calib folder")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="one seed, the interreflection at quarter resolution")
    ap.add_argument("--scale", type=int, default=2, help="camera reduction of the interreflection render (1: full)")
    ap.add_argument("--stride", type=int, default=2, help="camera pixels between the mesh's vertices")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    root, work = Path(args.data), Path(args.work)
    if not (root / "skull_2x3").is_dir():
        print(f"skull capture not found: {root}" + (" (skipped)" if args.quick else ""), file=sys.stderr)
        return 0 if args.quick else 2
    work.mkdir(parents=True, exist_ok=True)
    folder, system = root / "skull_2x3", root / "calibration" / "calibration.xml"
    real = work / "skull.h5"
    if not real.exists():
        export_capture(folder, real, reference_cloud=root / "skull_reference" / "pointCloud_from_skull_gray.mat",
                       reference_system=system)
    seeds = 1 if args.quick else args.seeds
    scale, stride = (4, 4) if args.quick else (args.scale, args.stride)
    sensor = capture_sensor(real, folder)
    if sensor["full_well_e"] is None:     # sensor_fit: sigma_I^2 does not grow with the background A
        print(f"{folder}: no sensor to fit (the noise does not grow with the background: {sensor['sigma_I']})",
              file=sys.stderr)
        return 2
    print(f"sensor fitted on the capture: full well {sensor['full_well_e']:.0f} e-, read noise "
          f"{sensor['read_noise_e']:.1f} e-, contrast B/A {sensor['contrast_median']:.2f}", flush=True)
    biases = {"sensor only": (None, "")}
    for win, loo in ((15, False), (9, True), (5, True)):
        b = unit_phase_bias(real, window=win, leave_one_out=loo)
        biases[f"+ measured bias {win}x{win}{' LOO' if loo else ''}"] = (b["bias"], f"rms {b['rms']:.4f} rad")
    biases["+ noise-only map 5x5 LOO"] = (None, "")
    biases.update(_interreflection_rows(real, system, work, scale, stride))
    rows = []
    wrong_real, n_real = _errors(real)
    spare = work / f"twin_{CACHE}_{_slug('sensor only')}_seed{seeds}.h5"
    if not spare.exists():
        pixel_twin(real, folder, spare, full_well_e=sensor["full_well_e"], read_noise_e=sensor["read_noise_e"], seed=seeds)
    for name, (bias, note) in biases.items():
        if name == "+ noise-only map 5x5 LOO":      # the 5x5 map of a sensor-only twin: no bias, its noise
            b = unit_phase_bias(spare, window=5, leave_one_out=True)
            bias, note = b["bias"], f"rms {b['rms']:.4f} rad"
        counts = []
        for seed in range(seeds):
            tag = f"_x{scale}_s{stride}" if "interreflection" in name and (scale, stride) != (2, 2) else ""
            out = work / f"twin_{CACHE}_{_slug(name)}{tag}_seed{seed}.h5"
            if not out.exists():
                pixel_twin(real, folder, out, full_well_e=sensor["full_well_e"], read_noise_e=sensor["read_noise_e"],
                           seed=seed, unit_bias=bias)
            counts.append(_errors(out))
        w = [c[0] for c in counts]
        rate = 100.0 * np.mean([c[0] / c[1] for c in counts])
        rows.append({"twin": name, "note": note, "wrong": w, "rate_pct": rate,
                     "real_over_twin": (100.0 * wrong_real / n_real) / max(rate, 1e-12)})
        print(f"{name:48s} {rate:.3f} % ({min(w)}-{max(w)})  real/twin {rows[-1]['real_over_twin']:.2f}  {note}",
              flush=True)
    _print_table(rows, seeds, wrong_real, n_real)
    if args.json:
        write_text(args.json, json.dumps({"real": {"wrong": wrong_real, "labelled": n_real}, "sensor": sensor,
                                          "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
