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
the range), real / twin, and the share of the twin's wrong pixels within 5 px of a real one
(chance: the share of the labelled pixels there). Then the evidence the docs quote
(:mod:`experiments.parity_evidence`, definitions there): the sensor against A and against B, the
contrast, where the real and the sensor-only twins' errors lie, which real errors look like the
reference's own, the response gamma that best explains the unit phase's deviation, and the pixel
twin's noise against the capture's and against its own sensor. Renders and twins are cached in
``--work`` (per interreflection render 23-36 s at half resolution, ``--scale 2 --stride 2``, the
default, 52-60 s at full, ``--scale 1``; ~10-25 s per twin; 2 shared cores at load 6-8; the capture
is read once, :func:`experiments.pixel_twin.measure_capture`); a twin's file name carries the sensor
fitted on the capture, so a changed noise estimate renders the twins afresh. Needs ``../shared/data``.
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


def _twin_file(work: Path, name: str, seed: int, sensor: dict, tag: str = "") -> Path:
    """The cached pixel twin of row ``name``: its name carries :data:`CACHE` and the sensor it was
    rendered with (full well, read noise), so that a changed noise estimate renders it afresh."""
    return work / (f"twin_{CACHE}_fw{sensor['full_well_e']:.0f}_rn{sensor['read_noise_e']:.2f}_{_slug(name)}{tag}"
                   f"_seed{seed}.h5")


def _errors(path) -> tuple[int, int, np.ndarray]:
    """(wrong, labelled, the wrong pixels (H, W) bool) of a file's MF 1 -> 16 decode."""
    from experiments.parity_evidence import decoded

    d = decoded(path)
    return int(d["wrong"].sum()), int(d["labelled"].sum()), d["wrong"]


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name).strip("_")


def _interreflection_rows(real, system, work: Path, scale: int, stride: int, measured) -> dict:
    """{row name: (bias (H, W) rad, note)} of the interreflection renders (cached in ``work``) and the
    last one scaled to the measured bias's amplitude."""
    from experiments.capture_gi import compare_bias, interreflection_bias
    from experiments.pixel_twin import unit_phase_bias

    biases = {}
    measured15 = unit_phase_bias(real, window=15, measured=measured)
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
                       f"measured: amplitude {1.0 / c['scale']:.2f} of the measured), {r['seconds']:.0f} s")
    # the last render with its amplitude scaled to the capture's measured bias (a fit to the bias map, not to
    # the error rate): what the missing indirect light (surfaces the camera does not see) would add
    biases[f"+ interreflection, albedo {albedo}, {bounces} bounces, x{c['scale']:.2f} (measured amplitude)"] = (
        r["bias"] * c["scale"], "amplitude fitted to the measured 15x15 bias map")
    return biases


def _print_table(rows, seeds: int, wrong_real: int, n_real: int, chance: float) -> None:
    print(f"\n| twin (seeds {seeds}) | traditional % | wrong | real / twin | within 5 px of a real error % | note |\n"
          "|---|---:|---:|---:|---:|---|")
    print(f"| real capture | {100.0 * wrong_real / n_real:.3f} | {wrong_real} | 1 | (chance {100 * chance:.1f}) | "
          f"{n_real} labelled pixels |")
    for r in rows:
        print(f"| {r['twin']} | {r['rate_pct']:.3f} | {min(r['wrong'])}-{max(r['wrong'])} | {r['real_over_twin']:.2f} | "
              f"{100 * min(r['near_real']):.0f}-{100 * max(r['near_real']):.0f} | {r['note']} |")


def _evidence(real, measured, sensor, spares) -> dict:
    """The section's other numbers (module docstring), printed; ``spares``: the sensor-only twins."""
    from experiments.learned_parity import capture_noise
    from experiments.parity_evidence import (contrast, decoded, error_places, fit_gamma, moved_orders, noise_match,
                                             reference_suspects, unit_deviation)
    from experiments.pixel_twin import measure_capture

    ev = {"sensor_A": {k: sensor[k] for k in ("A", "sigma_I", "full_well_e", "read_noise_e")}}
    print("\n== evidence (experiments.parity_evidence)")
    print("sensor against A (capture_sensor): A " + " ".join(f"{x:.3f}" for x in sensor["A"]) + "; sigma_I "
          + " ".join(f"{x:.4f}" for x in sensor["sigma_I"]) + f" -> {sensor['full_well_e']:.0f} e-, "
          f"{sensor['read_noise_e']:.1f} e-")
    cb = capture_noise(real)["curve"]
    ev["sensor_B"] = cb
    fw = "none" if cb["full_well_e"] is None else f"{cb['full_well_e']:.0f} e-, {cb['read_noise_e']:.1f} e-"
    print("sensor against B (capture_noise, traditional orders): B " + " ".join(f"{x:.3f}" for x in cb["modulation"])
          + "; sigma_I " + " ".join(f"{x:.4f}" for x in cb["sigma_I"]) + f" -> {fw}")
    ev["contrast"] = contrast(measured)
    print(f"contrast B/A of the top frequency: median {ev['contrast']['median']:.2f}, p10 {ev['contrast']['p10']:.2f}")
    mv = moved_orders(measured, decoded(real))
    ev["moved"] = mv
    print(f"orders the outlier pass moves on the capture: {mv['moved']} of {mv['decoded']} decoded pixels, "
          f"{mv['moved_labelled']} of them labelled")
    files = {"real capture": real, **{f"sensor-only twin, seed {i}": p for i, p in enumerate(spares)}}
    ev["places"], ev["suspects"] = {}, {}
    print("\n| file | wrong | components (largest px) | within 5 px of an invalid pixel (labelled there %) | "
          "median B wrong / labelled | labelled with B < 0.05: % wrong | looks like the reference's (plane 5x5) "
          "| genuine | neither / undecided |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name, path in files.items():
        d = decoded(path)
        pl = error_places(d["wrong"], d["labelled"], d["valid"], d["modulation_high"])
        su = reference_suspects(d["phase_high"], d["order_traditional"], d["order_reference"],
                                d["valid"] & (d["order_traditional"] >= 0))
        ev["places"][name] = pl
        ev["suspects"][name] = {k: v for k, v in su.items() if k != "reference_mask"}
        print(f"| {name} | {pl['wrong']} | {pl['components']} ({pl['largest']}) | {pl['near_invalid']} "
              f"({100 * pl['labelled_near_invalid']:.1f}) | {pl['median_B_wrong']:.3f} / {pl['median_B_labelled']:.3f} | "
              f"{100 * pl['low_B_rate']:.2f} of {pl['low_B_labelled']} | {su['reference']} | {su['traditional']} | "
              f"{su['neither']} / {su['undecided']} |")
    dev, u = unit_deviation(measured)
    g = fit_gamma(dev, u, measured.sets[0]["shifts"])
    ev["gamma"] = g
    print(f"\nresponse gamma that best explains the unit phase's deviation from the top phase's (|dev| < 0.3 rad, "
          f"{g['pixels']} px): {g['gamma']:.2f}{' (grid end)' if g['at_edge'] else ''}, rms {g['rms']:.5f} rad "
          f"(gamma 1: {g['rms_gamma_1']:.5f}), offset {g['offset']:.4f} rad, its bias amplitude {g['amplitude']:.4f} rad")
    twin = measure_capture(spares[0])
    nm = noise_match(measured, twin, full_well_e=sensor["full_well_e"], read_noise_e=sensor["read_noise_e"])
    ev["noise_match"] = nm
    print("pixel twin (sensor only, seed 0) vs capture, sigma_I per decile of A: capture "
          + " ".join(f"{x:.4f}" for x in nm["capture"]) + "; twin " + " ".join(f"{x:.4f}" for x in nm["twin"])
          + f"; largest difference {100 * nm['worst']:.1f} %")
    print("its true phase error per decile of B (B: true / sqrt(2/N) sigma_I / B / plane residual estimate, rad): "
          + " ".join(f"{r['B']:.3f}: {r['measured']:.4f}/{r['predicted']:.4f}/{r['estimated']:.4f}" for r in nm["true"])
          + f"; largest difference true vs sensor {100 * nm['true_worst']:.1f} %, estimate vs true "
          f"{100 * nm['estimator_worst']:.1f} %")
    print(f"unit phase's robust spread about its 15x15 bias: capture {nm['pixel_sd']['capture']:.4f} rad, "
          f"twin {nm['pixel_sd']['twin']:.4f} rad")
    return ev


def main(argv=None) -> int:
    from experiments.parity_evidence import error_coincidence
    from experiments.pixel_twin import capture_sensor, measure_capture, pixel_twin, unit_phase_bias
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
    measured = measure_capture(real, folder)      # the frames and the top phase read once for all twins
    sensor = capture_sensor(real, folder, measured=measured)
    if sensor["full_well_e"] is None:     # sensor_fit: sigma_I^2 does not grow with the background A
        print(f"{folder}: no sensor to fit (the noise does not grow with the background: {sensor['sigma_I']})",
              file=sys.stderr)
        return 2
    print(f"sensor fitted on the capture: full well {sensor['full_well_e']:.0f} e-, read noise "
          f"{sensor['read_noise_e']:.1f} e-, contrast B/A {sensor['contrast_median']:.2f}", flush=True)
    biases = {"sensor only": (None, "")}
    for win, loo in ((15, False), (9, True), (5, True)):
        b = unit_phase_bias(real, window=win, leave_one_out=loo, measured=measured)
        biases[f"+ measured bias {win}x{win}{' LOO' if loo else ''}"] = (b["bias"], f"rms {b['rms']:.4f} rad")
    biases["+ noise-only map 5x5 LOO"] = (None, "")
    biases.update(_interreflection_rows(real, system, work, scale, stride, measured))
    rows = []
    wrong_real, n_real, real_mask = _errors(real)
    from experiments.parity_evidence import decoded

    labelled = decoded(real)["labelled"]
    spare = _twin_file(work, "sensor only", seeds, sensor)
    if not spare.exists():
        pixel_twin(real, folder, spare, full_well_e=sensor["full_well_e"], read_noise_e=sensor["read_noise_e"], seed=seeds,
                   measured=measured)
    for name, (bias, note) in biases.items():
        if name == "+ noise-only map 5x5 LOO":      # the 5x5 map of a sensor-only twin: no bias, its noise
            b = unit_phase_bias(spare, window=5, leave_one_out=True)
            bias, note = b["bias"], f"rms {b['rms']:.4f} rad"
        counts = []
        for seed in range(seeds):
            tag = f"_x{scale}_s{stride}" if "interreflection" in name and (scale, stride) != (2, 2) else ""
            out = _twin_file(work, name, seed, sensor, tag)
            if not out.exists():
                pixel_twin(real, folder, out, full_well_e=sensor["full_well_e"], read_noise_e=sensor["read_noise_e"],
                           seed=seed, unit_bias=bias, measured=measured)
            counts.append(_errors(out))
        w = [c[0] for c in counts]
        rate = 100.0 * np.mean([c[0] / c[1] for c in counts])
        near = [error_coincidence(real_mask, c[2], labelled) for c in counts]
        rows.append({"twin": name, "note": note, "wrong": w, "rate_pct": rate,
                     "real_over_twin": (100.0 * wrong_real / n_real) / max(rate, 1e-12),
                     "near_real": [x["fraction"] for x in near], "chance": near[0]["chance"]})
        print(f"{name:48s} {rate:.3f} % ({min(w)}-{max(w)})  real/twin {rows[-1]['real_over_twin']:.2f}  {note}",
              flush=True)
    _print_table(rows, seeds, wrong_real, n_real, rows[0]["chance"])
    spares = [_twin_file(work, "sensor only", seed, sensor) for seed in range(seeds)]
    evidence = _evidence(real, measured, sensor, spares)
    if args.json:
        write_text(args.json, json.dumps({"real": {"wrong": wrong_real, "labelled": n_real}, "sensor": sensor,
                                          "rows": rows, "evidence": evidence}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
