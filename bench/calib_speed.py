"""`calib run` at the cost of its solver (issue 22): the command's wall time, peak memory and
stage profile beside the solve anchors, measured in the same run.

    python -m bench.calib_speed [--repeats 5] [--views 100] [--baseline DIR] [--quick]

Rows, each a fresh process (:func:`bench.deploy_speed.run_cli`: start-up, imports and figures
included), for ``calib run --observations ... -q``:

- the paper's 9 real views (../shared/data/dp-tpu; skipped without it) with the default figures
  (``residuals.png``), with ``--figures none`` and with ``--figures all`` (the per-pose panels);
- a simulated ``--views``-view joint session (:func:`bench.ba_scale._simulate`), default figures.

Columns: minimum and median wall seconds over ``--repeats`` runs, the largest peak memory (VmHWM),
and the stage profile the command itself records (``calibration.json`` ``run.stages_s``, of its
fastest run; an older checkout without it shows "-"; the rest of the wall time is start-up, imports,
reading the inputs and writing calibration.json). Anchors (same run): the solve of
``bench.ba_scale`` (ours joint, ours single camera, ``mrcal.optimize`` single camera) on 9 and
``--views`` simulated views. ``--baseline DIR``: an older checkout (``git archive REV | tar -x -C
DIR``) on the same inputs, rows marked [before]. The machine may be shared: read the ratios of rows
measured in the same run.
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
from pathlib import Path

from bench.deploy_speed import DP_TPU, ROOT, measure, mrcal_anchor


def _stages(stages) -> str:
    return "-" if not stages else "; ".join(f"{k} {v:.3f}" for k, v in stages.items())


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
          f"ratios); {args.repeats} run(s) per row\n")
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
        rows = []
        for k, (label, extra) in enumerate(cases):
            for tag, root in roots:
                out = tmp / f"out{k}_{tag}"
                rows.append((f"{label} [{tag}]", measure(["run", *extra, "-q"], root, out, args.repeats)))
        anchors = {v: mrcal_anchor(v, max(args.repeats, 1)) for v in (9, args.views)}
    print("## calib run --observations ... -q (fresh process each)\n")
    print("| command | wall s (min) | wall s (median) | peak MB | solve s (its own) | stages s (its fastest run) | "
          "rest s (start-up, imports, reading, json) | error |")
    print("|---|---:|---:|---:|---:|---|---:|---|")
    for name, r in rows:
        rest = min(r["walls"]) - sum(r["stages"].values()) if r["stages"] else None
        print(f"| {name} | {min(r['walls']):.3f} | {statistics.median(r['walls']):.3f} | {r['peak_mb']:.0f} | "
              f"{'-' if r['solve_s'] is None else format(r['solve_s'], '.3g')} | {_stages(r['stages'])} | "
              f"{'-' if rest is None else format(rest, '.3f')} | {r['error'] or ''} |")
    print("\n## Solve anchors (bench.ba_scale, simulated views, same run)\n")
    print("| views | ours joint solve s | ours single-camera solve s | mrcal single-camera s |\n|---:|---:|---:|---:|")
    for v, a in anchors.items():
        f = lambda x: "-" if x is None else format(x, ".3g")  # noqa: E731
        print(f"| {v} | {f(a['ours_joint_s'])} | {f(a['ours_single_s'])} | {f(a['mrcal_single_s'])} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
