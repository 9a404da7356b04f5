"""Bundle adjustment at scale: time, iterations and memory against views, and mrcal side by side.

    python -m bench.ba_scale [--views 9 30 100 300] [--repeats 3] [--baseline DIR] [--no-cli] [--quick]

Simulated sessions of the paper's system (``calib.default_system()``), the 9 x 11 circle board,
camera noise 0.06 px, projector noise 0.2 px, no outlier rejection. For each number of views, for
4 and 5 distortion terms:

- single device (the camera alone): seed (Zhang), build and solve time of ``run_calibration``, its
  iterations (linearisations), and ``mrcal.optimize`` on the identical problem from the same seed
  in the same process (regularisation and outlier rejection off), with the largest relative
  difference of the intrinsics;
- joint rig (camera + projector, shared board poses): the same times and iterations;
- time per iteration (solve / linearisations) and the peak resident memory of the process that ran
  our adjustment (each configuration runs in a fresh process, before mrcal is imported).

``--baseline DIR``: also run an older checkout's ``calib`` (e.g. ``git archive REV | tar -x -C
DIR``) on the same problems, for its iterations and times. Then ``calib run`` as a whole on the
paper's real observations (../shared/data/dp-tpu): wall time (min of repeats, start-up included)
and CPU time (start-up included) and where ``python -X importtime`` spends the start-up. Timings
are the minimum over repeats;
CPU times are given beside wall times because the machine may be shared. Prints Markdown tables.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DP_TPU = ROOT.parent / "shared" / "data" / "dp-tpu"


def _simulate(n_views: int):
    import numpy as np

    from calib import default_system
    from calib.board import Board
    from calib.simulate import simulate_observations

    board = Board("circles", 9, 11, 20.0, 5.0, 2.0, [[4, 5], [4, 6], [4, 7], [3, 5], [2, 5]])
    obs, _ = simulate_observations(default_system(), board, n_views, 0.06, np.random.default_rng(n_views),
                                   noise_prj_px=0.2)
    return obs


def _count_cpu_of_stages() -> dict:
    """CPU seconds of the seeding and of the solve inside ``run_calibration`` (the machine is shared:
    wall times include waiting for a core), collected by wrapping the functions it calls."""
    import calib.calibrate as C

    spent = {}
    for name in ("init_device", "solve"):
        fn = getattr(C, name)
        if getattr(fn, "_bench_wrapped", False):
            continue

        def timed(*a, _fn=fn, _name=name, **k):
            c0 = time.process_time()
            try:
                return _fn(*a, **k)
            finally:
                spent[_name] = spent.get(_name, 0.0) + time.process_time() - c0
        timed._bench_wrapped = True
        setattr(C, name, timed)
    return spent


def child(n_views: int, mode: str, n_dist: int, repeats: int, with_mrcal: bool) -> dict:
    """One configuration in this (fresh) process; returns the measurements."""
    import numpy as np

    from calib.adjustment.problem import BAConfig, DeviceConfig
    from calib.calibrate import run_calibration

    obs = _simulate(n_views)
    if mode == "single":
        obs = obs.only("camera")
    cfg = BAConfig(mode=mode, camera=DeviceConfig(n_dist), projector=DeviceConfig(n_dist), outlier_threshold=None)
    cpu = _count_cpu_of_stages()
    run_calibration(obs, cfg)                      # warm-up: kernels compiled / loaded, caches filled
    best = None
    for _ in range(repeats):
        cpu.clear()
        t0, c0 = time.perf_counter(), time.process_time()
        cal = run_calibration(obs, cfg)
        t = dict(cal.timings, wall_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0,
                 build_solve_s=cal.timings["build_s"] + cal.timings["solve_s"],
                 solve_cpu_s=cpu.get("solve", 0.0), seed_cpu_s=cpu.get("init_device", 0.0))
        best = t if best is None else {k: min(best[k], t[k]) for k in t}
    out = {"views": n_views, "mode": mode, "n_dist": n_dist, "points": int(sum(obs.count(d) for d in obs.devices())),
           "seed_s": best["init_s"], "build_s": best["build_s"], "solve_s": best["solve_s"], "total_s": best["wall_s"],
           "total_cpu_s": best["cpu_s"], "build_solve_s": best["build_solve_s"], "solve_cpu_s": best["solve_cpu_s"],
           "seed_cpu_s": best["seed_cpu_s"],
           "iterations": int(cal.ba.iterations), "evaluations": int(cal.ba.timings.get("evaluations", 0)),
           "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}
    if with_mrcal and mode == "single":
        from calib.adjustment.mrcal_reference import mrcal_calibrate
        from calib.rotation import matrix_from_rotvec

        s = cal.seeds["camera"]
        poses = [(matrix_from_rotvec(r), t) for r, t in zip(s.rvec_dev_board, s.t_dev_board)]
        times = []
        import mrcal

        cpu_m, optimize = [], mrcal.optimize

        def timed_optimize(*a, **k):                # CPU of the optimize call alone, as t_m is
            c0 = time.process_time()
            try:
                return optimize(*a, **k)
            finally:
                cpu_m.append(time.process_time() - c0)
        mrcal.optimize = timed_optimize
        for _ in range(repeats):
            theirs, _, t_m = mrcal_calibrate(obs, "camera", n_dist, s.K, s.distortion, poses)
            times.append(t_m)
        mrcal.optimize = optimize
        d = cal.system.camera
        ours = np.r_[d.fx, d.fy, d.cx, d.cy, d.distortion]
        rel = np.abs(ours - theirs) / np.abs(theirs)
        out.update(mrcal_s=min(times), mrcal_cpu_s=min(cpu_m), rel_core=float(rel[:4].max()),
                   rel_dist=float(rel[4:].max()))
    return out


def _run_child(args_list, pythonpath: str) -> dict:
    env = dict(os.environ, PYTHONPATH=pythonpath)
    proc = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", *map(str, args_list)],
                          capture_output=True, text=True, env=env, timeout=3600)
    if proc.returncode != 0:
        return {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else f"exit {proc.returncode}"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _fmt(v, spec):
    return "-" if v is None else format(v, spec)


def _table(rows, columns):
    """Markdown table of ``rows`` (dicts); ``columns``: (header, function of a row -> str)."""
    print("| " + " | ".join(h for h, _ in columns) + " |")
    print("|" + "---|" * len(columns))
    for r in rows:
        print("| " + " | ".join(f(r) for _, f in columns) + " |")


def _before(r, key):
    b = r.get("before") or {}
    return f"{b['iterations']}, {b[key]:.3f} s, {b['peak_rss_mb']:.0f} MB" if "iterations" in b else "-"


COMMON = [("views", lambda r: str(r["views"])), ("points", lambda r: str(r["points"])),
          ("dist terms", lambda r: str(r["n_dist"])), ("seed s", lambda r: f"{r['seed_s']:.4f}"),
          ("build s", lambda r: f"{r['build_s']:.4f}"),
          ("solve s (CPU s)", lambda r: f"{r['solve_s']:.4f} ({r.get('solve_cpu_s', float('nan')):.4f})"),
          ("iterations", lambda r: str(r["iterations"])),
          ("CPU ms / iteration", lambda r: f"{r['solve_cpu_s'] / r['iterations'] * 1e3:.2f}")]
SINGLE = COMMON + [("mrcal.optimize s (CPU s)", lambda r: f"{r['mrcal_s']:.4f} ({r['mrcal_cpu_s']:.4f})"),
                   ("solve / mrcal (CPU)", lambda r: f"{r['solve_s'] / r['mrcal_s']:.1f} ({r['solve_cpu_s'] / r['mrcal_cpu_s']:.1f})"),
                   ("max rel. diff fx fy cx cy", lambda r: f"{r['rel_core']:.1e}"),
                   ("max rel. diff distortion", lambda r: f"{r['rel_dist']:.1e}"),
                   ("before: iterations, solve, peak RSS", lambda r: _before(r, "solve_s"))]
JOINT = COMMON + [("seed + build + solve s (CPU s)", lambda r: f"{r['total_s']:.3f} ({r['total_cpu_s']:.3f})"),
                  ("peak RSS MB", lambda r: f"{r['peak_rss_mb']:.0f}"),
                  ("before: iterations, build + solve, peak RSS", lambda r: _before(r, "build_solve_s"))]


def scale_tables(views, repeats: int, baseline: str | None):
    rows = []
    for n_views in views:
        for n_dist in (4, 5):
            for mode in ("single", "joint"):
                r = _run_child([n_views, mode, n_dist, repeats, 1], str(ROOT))
                if baseline and n_views <= 100:
                    r["before"] = _run_child([n_views, mode, n_dist, 1, 0], baseline)
                rows.append(r)
                print(f"  measured {n_views} views, {n_dist} terms, {mode}: {r}", file=sys.stderr, flush=True)
    failed = [r for r in rows if "error" in r]
    rows = [r for r in rows if "error" not in r]
    print("### Single device (camera alone) vs mrcal.optimize on the identical problem\n")
    _table([r for r in rows if r["mode"] == "single"], SINGLE)
    print("\n### Joint rig (camera + projector)\n")
    _table([r for r in rows if r["mode"] == "joint"], JOINT)
    for r in failed:
        print(f"\nfailed: {r['error']}")


def _timed_runs(cmd, env, repeats: int):
    """(min wall s, min CPU s of the child) over ``repeats`` runs after one warm-up."""
    walls, cpus = [], []
    for k in range(repeats + 1):                # the first run may compile kernels
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run(cmd, env=env, check=True, capture_output=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if k:
            walls.append(time.perf_counter() - t0)
            cpus.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
    return min(walls), min(cpus)


def cli_table(repeats: int):
    cam, prj = DP_TPU / "CamCalibResult_real.mat", DP_TPU / "PrjCalibResult_real.mat"
    if not cam.exists():
        print("\n(../shared/data/dp-tpu absent: calib run not measured)")
        return
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-c", "import sys; from sltwin.cli import main; sys.exit(main(sys.argv[1:]))",
               "run", "--observations", str(cam), str(prj), "-o", tmp, "-q"]
        wall, cpu = _timed_runs(cmd, env, repeats)
        inner = re.search(r"total ([0-9.]+) s", subprocess.run(cmd, env=env, check=True, capture_output=True,
                                                                text=True).stdout)
        imp = subprocess.run([sys.executable, "-X", "importtime", *cmd[1:]], env=env, check=True,
                             capture_output=True, text=True).stderr
    mods = {}
    for line in imp.splitlines():
        m = re.match(r"import time:\s+(\d+) \|\s+(\d+) \|( *)(\S+)", line)
        if m and len(m.group(3)) <= 1:            # top-level imports: cumulative time
            mods[m.group(4)] = int(m.group(2)) / 1e6
    top = sorted(mods.items(), key=lambda kv: -kv[1])[:8]
    print("\n### `calib run --observations CamCalibResult_real.mat PrjCalibResult_real.mat` (paper's real data)\n")
    print(f"wall {wall:.2f} s, CPU {cpu:.2f} s (min of {repeats} after one warm-up, start-up included); seed + "
          f"build + solve inside: {inner.group(1) if inner else '?'} s; torch imported: "
          f"{'yes' if 'torch' in imp else 'no'}\n")
    print("| top-level import | cumulative s |")
    print("|---|---|")
    for name, t in top:
        print(f"| {name} | {t:.3f} |")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, nargs="+", default=[9, 30, 100, 300])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--baseline", help="an older checkout to run on the same problems (iterations, times)")
    ap.add_argument("--no-cli", action="store_true", help="skip the calib run measurement")
    ap.add_argument("--quick", action="store_true", help="9 and 30 views, one repeat (checks that it runs)")
    ap.add_argument("--child", nargs=5, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        v, mode, n_dist, repeats, with_mrcal = args.child
        print(json.dumps(child(int(v), mode, int(n_dist), int(repeats), bool(int(with_mrcal)))))
        return
    if args.quick:
        args.views, args.repeats = [v for v in args.views if v <= 30] or [9], 1
    print(f"machine: {os.cpu_count()} CPU(s), load average {os.getloadavg()[0]:.1f} at start "
          "(shared with other jobs: times are upper bounds)\n")
    scale_tables(args.views, args.repeats, args.baseline)
    if not args.no_cli:
        cli_table(args.repeats)


if __name__ == "__main__":
    main()
