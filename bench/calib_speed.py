"""`calib run` at the cost of its solver (issue 22): the command's wall time, peak memory and
stage profile beside the solve anchors, measured in the same run.

    python -m bench.calib_speed [--repeats 5] [--views 100] [--baseline DIR] [--quick]

Rows, each a fresh process (:func:`bench.deploy_speed.run_cli`: start-up, imports and figures
included), for ``calib run --observations ... -q``:

- the paper's 9 real views (../shared/data/dp-tpu; skipped without it) with the default figures
  (``residuals.png``), with ``--figures none`` and with ``--figures all`` (the per-pose panels);
- a simulated ``--views``-view joint session (:func:`bench.ba_scale._simulate`), default figures.

Columns: minimum and median wall seconds over ``--repeats`` runs, the mean CPU seconds (user +
system of the child process: what a loaded machine's wall time hides), the largest peak memory
(VmHWM), the ratio after / before of the median wall and of the CPU (``--baseline``), and the
stage profile the command itself records (``calibration.json`` ``run.stages_s``, of its fastest
run; an older checkout without it shows "-"; the rest of the wall time is start-up, imports,
reading the inputs and writing calibration.json). Anchors (same run): the solve of
``bench.ba_scale`` (ours joint, ours single camera, ``mrcal.optimize`` single camera) on 9 and
``--views`` simulated views. ``--baseline DIR``: an older checkout (``git archive REV | tar -x -C
DIR``) on the same inputs, rows marked [before], the runs of a row alternating after / before; with
it, the paper's calibration of the two checkouts compared (every K, distortion, R, t entry: the
largest relative difference; issue 22 holds it within 1e-9). The machine may be shared: read the
ratios of rows measured in the same run.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import tempfile
from pathlib import Path

import numpy as np

from bench.deploy_speed import DP_TPU, ROOT, bytecode_note, measure, mrcal_anchor


def _stages(stages) -> str:
    return "-" if not stages else "; ".join(f"{k} {v:.3f}" for k, v in stages.items())


def _children_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _measure_cpu(argv, root, out, repeats: int) -> dict:
    """:func:`bench.deploy_speed.measure` with the mean CPU seconds (user + system) of its runs."""
    c0 = _children_cpu_s()
    r = measure(argv, root, out, repeats)
    r["cpu_s"] = (_children_cpu_s() - c0) / max(repeats, 1)
    return r


def _merge(a: dict, b: dict) -> dict:
    """Two :func:`_measure_cpu` results of one command as one (their runs together)."""
    if a is None:
        return b
    n_a, n_b = len(a["walls"]), len(b["walls"])
    fastest = b if min(b["walls"]) < min(a["walls"]) else a
    return {"walls": a["walls"] + b["walls"], "peak_mb": max(a["peak_mb"], b["peak_mb"]),
            "stages": fastest["stages"], "solve_s": fastest["solve_s"], "error": a["error"] or b["error"],
            "cpu_s": (a["cpu_s"] * n_a + b["cpu_s"] * n_b) / (n_a + n_b)}


def max_relative_difference(after: Path, before: Path) -> float:
    """The largest |a - b| / max(|b|, 1e-9 max|b| of its block) over the camera's and projector's
    K, distortion, R and t in two ``calibration.json`` files."""
    a, b = json.loads(after.read_text()), json.loads(before.read_text())
    worst = 0.0
    for dev in ("camera", "projector"):
        for key in ("K", "distortion", "R", "t"):
            x, y = (np.ravel(np.asarray(c[dev][key], dtype=float)) for c in (a, b))
            if x.shape != y.shape:
                return float("inf")
            scale = np.maximum(np.abs(y), 1e-9 * max(np.abs(y).max(), 1e-300))
            worst = max(worst, float((np.abs(x - y) / scale).max()) if len(y) else 0.0)
    return worst


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--views", type=int, default=100, help="views of the simulated joint session")
    ap.add_argument("--baseline", help="an older checkout to run beside (before / after rows)")
    ap.add_argument("--quick", action="store_true", help="1 repeat, 20 views")
    args = ap.parse_args(argv)
    if args.quick:
        args.repeats, args.views = 1, 20
    roots = [("after", ROOT)] + ([("before", Path(args.baseline).resolve())] if args.baseline else [])
    print(f"machine: {os.cpu_count()} CPU(s), load average {os.getloadavg()[0]:.1f} at start (shared: read the "
          f"ratios); {args.repeats} run(s) per row")
    print(f"{bytecode_note()}\n")
    with tempfile.TemporaryDirectory(prefix="calib_speed_") as tmp:
        tmp = Path(tmp)
        from bench.ba_scale import _simulate
        from calib.observations import write_observations_json

        obs_json = write_observations_json(_simulate(args.views), tmp / f"obs{args.views}.json")
        paper = [DP_TPU / "CamCalibResult_real.mat", DP_TPU / "PrjCalibResult_real.mat"]
        cases = []
        if all(p.is_file() for p in paper):
            cases += [("paper's 9 views", ["--observations", *paper]),
                      ("paper's 9 views, --figures none", ["--observations", *paper, "--figures", "none"]),
                      ("paper's 9 views, --figures all", ["--observations", *paper, "--figures", "all"])]
        cases.append((f"{args.views}-view joint session", ["--observations", obs_json]))
        rows, same = [], None
        for k, (label, extra) in enumerate(cases):
            got = {tag: None for tag, _ in roots}
            for _ in range(args.repeats):         # after / before alternating: both see the same load
                for tag, root in roots:
                    got[tag] = _merge(got[tag], _measure_cpu(["run", *extra, "-q"], root, tmp / f"out{k}_{tag}", 1))
            rows += [(f"{label} [{tag}]", tag, label, got[tag]) for tag, _ in roots]
            if k == 0 and args.baseline and cases[0][0].startswith("paper") and \
                    all((tmp / f"out0_{t}" / "calibration.json").is_file() for t in ("after", "before")):
                same = max_relative_difference(tmp / "out0_after" / "calibration.json",
                                               tmp / "out0_before" / "calibration.json")
        anchors = {v: mrcal_anchor(v, max(args.repeats, 1)) for v in (9, args.views)}
    print("## calib run --observations ... -q (fresh process each)\n")
    print("| command | wall s (min) | wall s (median) | CPU s (mean) | peak MB | after / before (median wall; CPU) | "
          "solve s (its own) | stages s (its fastest run) | rest s (start-up, imports, reading, json) | error |")
    print("|---|---:|---:|---:|---:|---:|---:|---|---:|---|")
    by = {(label, tag): r for _, tag, label, r in rows}
    for name, tag, label, r in rows:
        rest = min(r["walls"]) - sum(r["stages"].values()) if r["stages"] else None
        base = by.get((label, "before")) if tag == "after" else None
        ratio = "-" if base is None else (f"{statistics.median(r['walls']) / statistics.median(base['walls']):.2f}; "
                                          f"{r['cpu_s'] / base['cpu_s']:.2f}")
        print(f"| {name} | {min(r['walls']):.3f} | {statistics.median(r['walls']):.3f} | {r['cpu_s']:.3f} | "
              f"{r['peak_mb']:.0f} | {ratio} | {'-' if r['solve_s'] is None else format(r['solve_s'], '.3g')} | "
              f"{_stages(r['stages'])} | {'-' if rest is None else format(rest, '.3f')} | {r['error'] or ''} |")
    if same is not None:
        print(f"\nThe paper's calibration, after against before: every camera / projector K, distortion, R, t entry "
              f"within {same:.1e} relative (issue 22: <= 1e-9).")
    print(f"\nload average at the end: {os.getloadavg()[0]:.1f}")
    print("\n## Solve anchors (bench.ba_scale, simulated views, same run)\n")
    print("| views | ours joint solve s | ours single-camera solve s | mrcal single-camera s |\n|---:|---:|---:|---:|")
    for v, a in anchors.items():
        f = lambda x: "-" if x is None else format(x, ".3g")  # noqa: E731
        print(f"| {v} | {f(a['ours_joint_s'])} | {f(a['ours_single_s'])} | {f(a['mrcal_single_s'])} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
