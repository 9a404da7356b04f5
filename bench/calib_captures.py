"""What accuracy costs, from images: ``calib render-board`` sessions in the twin -> ``calib run``.

    python -m bench.calib_captures                 # cost table + spread over 10 noise draws
    python -m bench.calib_captures --draws 30 --only spread [--jitter DEG MM]
    python -m bench.calib_captures --quick         # the paper's session once, and 2 draws

The twin is the built-in real system without skew and distortion (what Blender represents), so
every estimate has an exactly known true value. Table 1 varies one factor of the paper's session
at a time (views 3/5/9/15; steps 3/4/12; frequency sets (1, 8, 48) vs (1, 48); 0 vs 5 distortion
terms) and reports the predicted standard deviation of the camera's fx and of the projector's fy,
the reprojection RMS, the largest |estimate - truth| / sigma over the 8 intrinsics, and the time
each stage costs (images, rendering, decoding + detection + phase fit, adjustment). Table 2
repeats the paper's session over independent noise draws: the spread of each intrinsic's estimate
against its mean predicted standard deviation (ratio 1 = the uncertainty is what the adjustment
says) and the mean error in sigma units (bias).
"""
from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

INTRINSICS = [(d, p) for d in ("camera", "projector") for p in ("fx", "fy", "cx", "cy")]


def twin_system():
    from calib import default_system

    return default_system().ideal({"name": "ideal-pinhole twin of the built-in system"})


def one_session(truth_system, work: Path, *, views=9, steps=12, frequencies=(1, 8, 48), n_dist=5, seed=0,
                jitter=None) -> dict:
    """Render, observe and calibrate one session; returns estimates, sigmas and timings."""
    from calib.bundle_adjustment import BAConfig, DeviceConfig
    from calib.calibrate import run_calibration
    from calib.captures import observations_from_captures
    from synth.board_session import render_board_session

    folder = work / f"s_{views}_{steps}_{'-'.join(map(str, frequencies))}_{seed}"
    if folder.exists():
        shutil.rmtree(folder)
    t0 = time.perf_counter()
    render_board_session(folder, truth_system, steps=steps, frequencies=frequencies, n_poses=views, seed=seed,
                         jitter=jitter)
    t1 = time.perf_counter()
    co = observations_from_captures(folder)
    t2 = time.perf_counter()
    cal = run_calibration(co.observations, BAConfig(camera=DeviceConfig(n_dist), projector=DeviceConfig(n_dist)))
    t3 = time.perf_counter()
    n_images = sum(1 for _ in folder.glob("pose_*/*.png"))
    shutil.rmtree(folder)
    est = {f"{d}.{p}": getattr(getattr(cal.system, d), p) for d, p in INTRINSICS}
    true = {f"{d}.{p}": getattr(getattr(truth_system, d), p) for d, p in INTRINSICS}
    std = {k: cal.ba.std[k] for k in est}
    stats = cal.ba.stats
    return {"est": est, "true": true, "std": std, "images": n_images,
            "rms": {d: stats[d]["rms_px"] for d in ("camera", "projector")},
            "seconds": {"render": t1 - t0, "observe": t2 - t1, "adjust": t3 - t2},
            "max_z": max(abs(est[k] - true[k]) / std[k] for k in est)}


def cost_table(truth_system, work: Path, out=sys.stdout, *, quick: bool = False) -> None:
    paper = dict(views=9, steps=12, frequencies=(1, 8, 48), n_dist=5)
    rows = [dict(paper, views=v) for v in ((9,) if quick else (3, 5, 9, 15))]
    if not quick:
        rows += [dict(paper, steps=s) for s in (3, 4)]
        rows += [dict(paper, frequencies=(1, 48))]
        rows += [dict(paper, n_dist=0)]
    print("\n### What accuracy costs (one noise draw each; truth = the ideal twin)\n", file=out)
    print("| views | steps | frequencies | dist terms | images | std cam fx px | std prj fy px | RMS cam px |"
          " RMS prj px | max abs(z) | render s | decode+detect+fit s | adjust s |", file=out)
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|", file=out)
    for cfg in rows:
        label = (f"| {cfg['views']} | {cfg['steps']} | {', '.join(map(str, cfg['frequencies']))} | "
                 f"{cfg['n_dist']} |")
        try:
            r = one_session(truth_system, work, **cfg)
        except ValueError as exc:
            print(f"{label} refused: {str(exc)[:120]} |", file=out, flush=True)
            continue
        s = r["seconds"]
        print(f"{label} {r['images']} | {r['std']['camera.fx']:.3f} | {r['std']['projector.fy']:.3f} | "
              f"{r['rms']['camera']:.4f} | {r['rms']['projector']:.4f} | {r['max_z']:.2f} | "
              f"{s['render']:.1f} | {s['observe']:.1f} | {s['adjust']:.1f} |", file=out, flush=True)


def spread_interval(draws: int, level: float = 0.90) -> tuple[float, float]:
    """Interval holding ``sample std / true std`` with probability ``level`` for ``draws``
    Gaussian draws (chi distribution with draws - 1 degrees of freedom)."""
    from scipy.stats import chi2

    dof = draws - 1
    a = (1 - level) / 2
    return float(np.sqrt(chi2.ppf(a, dof) / dof)), float(np.sqrt(chi2.ppf(1 - a, dof) / dof))


def spread_table(truth_system, work: Path, draws: int, out=sys.stdout, *, jitter=(1.0, 5.0), save=None) -> dict:
    """Repeat the paper's session ``draws`` times (new sensor noise; with ``jitter`` every board
    pose placed again at random, ``synth.board_session.pose_jitter``) and compare the spread of
    each intrinsic's estimate with its mean predicted sigma. Returns {parameter: spread / sigma}
    plus ``"_pooled_rms_z"``: the RMS of (estimate - truth) / sigma over all draws and intrinsics.
    ``save``: a JSON-lines file; draws already in it (same seed and jitter) are reused, new ones
    appended, so a long run can be resumed."""
    import json

    done = {}
    if save is not None and Path(save).exists():
        for line in Path(save).read_text().splitlines():
            r = json.loads(line)
            if r.get("jitter") == (list(jitter) if jitter else None):
                done[r["seed"]] = r
    runs = []
    for k in range(draws):
        seed = 100 + k
        if seed in done:
            runs.append(done[seed])
            continue
        r = one_session(truth_system, work, seed=seed, jitter=jitter)
        r.update(seed=seed, jitter=list(jitter) if jitter else None)
        runs.append(r)
        if save is not None:
            with open(save, "a") as f:
                f.write(json.dumps(r) + "\n")
        print(f"draw {k + 1}/{draws}: max |z| {runs[-1]['max_z']:.2f}, RMS cam/prj "
              f"{runs[-1]['rms']['camera']:.4f}/{runs[-1]['rms']['projector']:.4f} px", file=sys.stderr, flush=True)
    what = ("sensor noise and board poses (jitter: rotation <= %g deg, translation <= %g mm per pose)" % tuple(jitter)
            if jitter else "sensor noise only (same board poses)")
    lo, hi = spread_interval(draws)
    print(f"\n### Spread over {draws} repeated sessions vs the predicted sigma ({what})\n", file=out)
    print(f"With {draws} draws, spread / sigma of a correctly predicted sigma lies in [{lo:.2f}, {hi:.2f}] "
          "with 90 % probability (chi distribution).\n", file=out)
    print("| parameter | true | mean estimate | spread (std over draws) | mean predicted sigma | spread / sigma |"
          " mean z | RMS z | draws within 3 sigma |", file=out)
    print("|---|---|---|---|---|---|---|---|---|", file=out)
    result, all_z = {}, []
    for key in runs[0]["est"]:
        est = np.array([r["est"][key] for r in runs])
        sig = np.array([r["std"][key] for r in runs])
        true = runs[0]["true"][key]
        z = (est - true) / sig
        all_z.append(z)
        spread = float(np.std(est, ddof=1))
        result[key] = spread / float(np.mean(sig))
        print(f"| {key} | {true:.3f} | {est.mean():.3f} | {spread:.3f} | {sig.mean():.3f} | {result[key]:.2f} | "
              f"{z.mean():+.2f} | {np.sqrt(np.mean(z ** 2)):.2f} | {int(np.sum(np.abs(z) <= 3))}/{draws} |",
              file=out, flush=True)
    all_z = np.concatenate(all_z)
    result["_pooled_rms_z"] = float(np.sqrt(np.mean(all_z ** 2)))
    print(f"\nPooled over the 8 intrinsics and {draws} draws: RMS z {result['_pooled_rms_z']:.2f} "
          f"(1 = the predicted sigma is the actual error), {int(np.sum(np.abs(all_z) <= 3))}/{all_z.size} "
          "within 3 sigma.", file=out, flush=True)
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=10, help="noise draws of the spread table (default 10)")
    ap.add_argument("--only", choices=("cost", "spread"), help="run one table only")
    ap.add_argument("--save", metavar="JSONL", help="keep every draw in this file and reuse it when run again")
    ap.add_argument("--jitter", type=float, nargs=2, default=(1.0, 5.0), metavar=("DEG", "MM"),
                    help="per-draw random board pose perturbation (default 1 deg, 5 mm; 0 0: noise only)")
    ap.add_argument("--quick", action="store_true", help="the paper's session only in the cost table, 2 draws")
    args = ap.parse_args(argv)
    draws = 2 if args.quick else args.draws
    truth = twin_system()
    with tempfile.TemporaryDirectory(prefix="sltwin-bench-") as tmp:
        work = Path(tmp)
        if args.only in (None, "cost"):
            cost_table(truth, work, quick=args.quick)
        if args.only in (None, "spread"):
            spread_table(truth, work, draws, jitter=tuple(args.jitter) if any(args.jitter) else None,
                         save=args.save)
    print("\n(2-core CPU; times are wall-clock seconds of this run)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
