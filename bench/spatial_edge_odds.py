"""Calibrate the graph cut's depth-edge odds (``unwrap.spatial_orders.DEFAULTS["step_odds"]``,
:mod:`unwrap.spatial_edges`) on the twin validation scenes, and print the grid.

    python -m bench.spatial_edge_odds --work DIR [--odds 0,0.01,...] [--smoothness 8,16] [--json OUT] [--quick]

Scenes: the validation set of ``python -m bench.spatial_unwrap --calibrate-gate`` (rendered once
into ``--work``, the same cache): the 6 noise-dominated scenes of ``bench/data/spatial_val.toml``
and the 6 interreflection scenes of ``bench/data/decision_error_val.toml``. Never a real capture,
never the beat-wrap pairs or the test sets.

Rule (the one the smoothness and outlier weights were chosen by, docs/learned.md "The graph cut's
weights recalibrated"): the least ungated graph-cut error pooled over the 6 noise-dominated scenes;
ties go to the smaller odds. Also printed per odds: the interreflection scenes' error, the scenes
worse than traditional, and the shipped gate's worst broken / fixed ratio on the noise-dominated
scenes (its calibration rule: at most ``bench.spatial_unwrap.BREAK_RATIO``).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

#: odds of a whole-fringe depth step against one surface per edge (0: the weights unchanged)
ODDS_GRID = (0.0, 0.01, 0.03, 0.1, 0.3, 1.0, 3.0)


def grid(items, odds_grid, smoothness_grid, quiet=False) -> list:
    """Rows {odds, smoothness, noise / bias: [wrong, traditional wrong, counted], worse, gate_worst}."""
    from tqdm import tqdm

    from bench.spatial_unwrap import _sigmas
    from unwrap.decision_error import error_probability
    from unwrap.spatial_orders import GATE, gate, graphcut_orders
    from unwrap.temporal import decode_pair

    base = []
    for it in items:
        _, n, ok = decode_pair("mf", it["phase_low"], it["phase_high"], *it["freqs"], it["width"], it["valid"])
        base.append((n, ok, ok & (it["ref"] >= 0)))
    rows = []
    combos = [(o, s) for s in smoothness_grid for o in odds_grid]
    for odds, lam in tqdm(combos, desc="odds x smoothness", disable=quiet, file=sys.stderr):
        row = {"odds": odds, "smoothness": lam, "noise": [0, 0, 0], "bias": [0, 0, 0], "worse": [], "gate_worst": 0.0,
               "scenes": []}
        for it, (n, ok, m) in zip(items, base):
            s_lo, s_hi = _sigmas(it)
            r = graphcut_orders("mf", it["phase_low"], it["phase_high"], it["freqs"], ok, s_lo, s_hi,
                                width=it["width"], smoothness=lam, step_odds=odds)
            key = "bias" if "bias-val" in it["name"] else "noise"
            bad, bad_t = (r.order != it["ref"]) & m, (n != it["ref"]) & m
            row[key][0] += int(bad.sum())
            row[key][1] += int(bad_t.sum())
            row[key][2] += int(m.sum())
            row["scenes"].append([it["name"], int(bad.sum()), int(bad_t.sum())])
            if bad.sum() > bad_t.sum():
                row["worse"].append(it["name"])
            if key == "noise":
                p = error_probability(r.p_wrong_traditional, r.prior, ok, it["m_low"], it["m_high"])
                g = gate(r.order, n, ok, p, **GATE["Graph cut"])
                fixed = int((bad_t & (g == it["ref"]))[m].sum())
                broken = int((~bad_t & (g != it["ref"]))[m].sum())
                row["gate_worst"] = max(row["gate_worst"], broken / max(fixed, 1))
        rows.append(row)
        if not quiet:
            print(f"  odds {odds:g} smoothness {lam:g}: noise {row['noise'][0]} wrong, interreflection "
                  f"{row['bias'][0]} wrong, worse on {len(row['worse'])} scenes, gated worst broken/fixed "
                  f"{row['gate_worst']:.3f}", file=sys.stderr, flush=True)
    return rows


def choose(rows) -> dict:
    """The rule of the module docstring."""
    return min(rows, key=lambda r: (r["noise"][0], r["odds"]))


def table(rows) -> str:
    lines = ["| step odds | smoothness | noise-dominated: wrong (%) | interreflection: wrong (%) | scenes worse than "
             "traditional | gated worst broken / fixed (noise) |", "|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        nz, bs = r["noise"], r["bias"]
        lines.append(f"| {r['odds']:g} | {r['smoothness']:g} | {nz[0]:,} ({100 * nz[0] / max(nz[2], 1):.3f}) | "
                     f"{bs[0]:,} ({100 * bs[0] / max(bs[2], 1):.3f}) | {len(r['worse'])} | {r['gate_worst']:.3f} |")
    r0 = rows[0]
    lines.append(f"\ntraditional: noise-dominated {r0['noise'][1]:,} of {r0['noise'][2]:,}, interreflection "
                 f"{r0['bias'][1]:,} of {r0['bias'][2]:,}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.spatial_edge_odds", description=__doc__.split("\n")[0])
    ap.add_argument("--work", default="/tmp/sltwin_bench_spatial", help="cache of the validation renders")
    ap.add_argument("--odds", default=",".join(f"{o:g}" for o in ODDS_GRID))
    ap.add_argument("--smoothness", default=None, help="comma-separated (default: the shipped one)")
    ap.add_argument("--json", default=None)
    ap.add_argument("-q", "--quiet", action="store_true")
    ap.add_argument("--quick", action="store_true",
                    help="one interreflection scene, odds 0 and the shipped one: a smoke run, not the calibration")
    args = ap.parse_args(argv)
    from bench.spatial_unwrap import bias_items, validation_items
    from unwrap.spatial_orders import DEFAULTS

    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    odds = [0.0, DEFAULTS["step_odds"]] if args.quick else [float(v) for v in args.odds.split(",")]
    lams = [float(v) for v in args.smoothness.split(",")] if args.smoothness else [DEFAULTS["smoothness"]]
    items = bias_items(work, limit=1) if args.quick else validation_items(work)
    rows = grid(items, odds, lams, args.quiet)
    print(table(rows))
    best = choose(rows)
    if args.quick:
        print("\n(--quick: one interreflection scene, a smoke run; no odds chosen)")
    else:
        print(f"\ncalibrated step odds (least noise-dominated validation error): {best['odds']:g} "
              f"(smoothness {best['smoothness']:g})")
    if args.json:
        from unwrap.safe_output import write_text
        write_text(Path(args.json), json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
