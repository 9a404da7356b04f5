"""What accuracy costs, from images: ``calib render-board`` sessions in the twin -> ``calib run``.

    python -m bench.calib_captures                 # cost table + spread over 10 noise draws
    python -m bench.calib_captures --draws 30 --only spread [--jitter DEG MM]
    python -m bench.calib_captures --quick         # the paper's session once, and 2 draws
    python -m bench.calib_captures --only spread --system real --distortion 5 4 --skew both --draws 60

``--system`` picks the truth that is rendered: ``twin`` (default: the built-in real system without
skew and distortion, what Blender represents), ``real`` (the built-in system as it is: distorted
and skewed) or ``real-noskew`` (distorted, skew 0), so every estimate has an exactly known true
value. Table 1 varies one factor of the paper's session
at a time (views 3/5/9/15; steps 3/4/12; frequency sets (1, 8, 48) vs (1, 48); 0 vs 5 distortion
terms) and reports the predicted standard deviation of the camera's fx and of the projector's fy,
the reprojection RMS, the largest |estimate - truth| / sigma over the 8 intrinsics, and the time
each stage costs (images, rendering, decoding + detection + phase fit, adjustment). Table 2
repeats the paper's session over independent draws (sensor noise, board placed again): the
spread of each estimated intrinsic (fx fy cx cy, skew when estimated, the distortion terms)
against its mean predicted standard deviation (ratio 1 = the uncertainty is what the adjustment
says) and the mean error in sigma units (bias); every model of ``--distortion`` x ``--skew`` is
fitted to the same rendered draws, one table each.
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
DISTORTION_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4")
SYSTEMS = ("twin", "real", "real-noskew")


def truth_system(name: str = "twin"):
    """The system a benchmark renders: ``twin`` (no skew, no distortion), ``real`` (the built-in
    system: distorted and skewed) or ``real-noskew`` (distorted, skew 0)."""
    from calib import default_system

    from calib.system import SystemModel

    s = default_system()
    if name == "real":
        return s
    if name == "twin":
        return s.ideal({"name": "ideal-pinhole twin of the built-in system"})
    if name == "real-noskew":
        return SystemModel(s.camera.without_skew(), s.projector.without_skew(), {"name": "built-in system, skew 0"})
    raise ValueError(f"system: expected one of {SYSTEMS}, got {name!r}")


def twin_system():
    """The ideal-pinhole twin of the built-in system (``truth_system("twin")``)."""
    return truth_system("twin")


def model_label(n_dist: int, skew: bool) -> str:
    return f"{n_dist} terms, skew {'estimated' if skew else 'fixed at 0'}"


def observe_session(truth_system, work: Path, *, views=9, steps=12, frequencies=(1, 8, 48), seed=0,
                    jitter=None):
    """Render one session of ``truth_system`` and observe it (unwrap, detect, phase fit).
    Returns (Observations, number of images, {"render": s, "observe": s})."""
    from calib.detect.captures import observations_from_captures
    from synth.scenes.board_session import render_board_session

    folder = work / f"s_{views}_{steps}_{'-'.join(map(str, frequencies))}_{seed}"
    if folder.exists():
        shutil.rmtree(folder)
    t0 = time.perf_counter()
    render_board_session(folder, truth_system, steps=steps, frequencies=frequencies, n_poses=views, seed=seed,
                         jitter=jitter)
    t1 = time.perf_counter()
    co = observations_from_captures(folder)
    t2 = time.perf_counter()
    n_images = sum(1 for _ in folder.glob("pose_*/*.png"))
    shutil.rmtree(folder)
    return co.observations, n_images, {"render": t1 - t0, "observe": t2 - t1}


def true_intrinsics(truth_system, n_dist: int, skew: bool) -> dict:
    """{"camera.fx": value, ...}: fx fy cx cy (+ skew when estimated, + the model's distortion
    terms; a term the true lens lacks is 0) of both devices."""
    out = {}
    for d in ("camera", "projector"):
        dev = getattr(truth_system, d)
        names = ["fx", "fy", "cx", "cy"] + (["skew"] if skew else [])
        out.update({f"{d}.{p}": getattr(dev, p) for p in names})
        dist = list(dev.distortion) + [0.0] * 12
        out.update({f"{d}.{DISTORTION_NAMES[k]}": float(dist[k]) for k in range(n_dist)})
    return out


def fit_session(obs, truth_system, *, n_dist=5, skew=False) -> dict:
    """Calibrate ``obs`` with ``n_dist`` distortion terms (skew estimated or fixed at 0);
    returns estimates, truths, sigmas, residual RMS and the adjustment's time."""
    from calib.adjustment.problem import BAConfig, DeviceConfig
    from calib.calibrate import run_calibration

    t0 = time.perf_counter()
    cal = run_calibration(obs, BAConfig(camera=DeviceConfig(n_dist, skew), projector=DeviceConfig(n_dist, skew)))
    seconds = time.perf_counter() - t0
    true = true_intrinsics(truth_system, n_dist, skew)
    est = {}
    for key in true:
        d, p = key.split(".")
        dev = getattr(cal.system, d)
        est[key] = float(dev.distortion[DISTORTION_NAMES.index(p)]) if p in DISTORTION_NAMES else getattr(dev, p)
    std = {k: cal.ba.std[k] for k in est}
    stats = cal.ba.stats
    basic = [f"{d}.{p}" for d, p in INTRINSICS]
    return {"est": est, "true": true, "std": std, "model": model_label(n_dist, skew),
            "rms": {d: stats[d]["rms_px"] for d in ("camera", "projector")}, "adjust_s": seconds,
            "max_z": max(abs(est[k] - true[k]) / std[k] for k in basic)}


def one_session(truth_system, work: Path, *, views=9, steps=12, frequencies=(1, 8, 48), n_dist=5, seed=0,
                jitter=None, skew=False) -> dict:
    """Render, observe and calibrate one session; returns estimates, sigmas and timings."""
    obs, n_images, seconds = observe_session(truth_system, work, views=views, steps=steps, frequencies=frequencies,
                                             seed=seed, jitter=jitter)
    r = fit_session(obs, truth_system, n_dist=n_dist, skew=skew)
    r.update(images=n_images, seconds=dict(seconds, adjust=r.pop("adjust_s")))
    return r


def cost_table(truth_system, work: Path, out=sys.stdout, *, quick: bool = False) -> None:
    paper = dict(views=9, steps=12, frequencies=(1, 8, 48), n_dist=5)
    rows = [dict(paper, views=v) for v in ((9,) if quick else (3, 5, 9, 15))]
    if not quick:
        rows += [dict(paper, steps=s) for s in (3, 4)]
        rows += [dict(paper, frequencies=(1, 48))]
        rows += [dict(paper, n_dist=0)]
    print(f"\n### What accuracy costs (one noise draw each; truth = {truth_system.meta.get('name', 'given system')})\n",
          file=out)
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


def _saved_draws(save, key) -> dict:
    """{(seed, model label): result} of the draws in the JSON-lines file ``save`` made with ``key``
    (system name and jitter)."""
    import json

    done = {}
    if save is not None and Path(save).exists():
        for line in Path(save).read_text().splitlines():
            r = json.loads(line)
            if (r.get("system", "twin"), r.get("jitter")) == key and "model" in r:
                done[(r["seed"], r["model"])] = r
    return done


def spread_table(truth_system, work: Path, draws: int, out=sys.stdout, *, jitter=(1.0, 5.0), save=None,
                 models=((5, False),), system_name: str = "twin") -> dict:
    """Repeat the paper's session ``draws`` times (new sensor noise; with ``jitter`` every board
    pose placed again at random, ``synth.scenes.board_session.pose_jitter``), fit every model
    ``(n_dist, skew)`` of ``models`` to each rendered draw, and compare the spread of each
    intrinsic's estimate with its mean predicted sigma, one table per model. Returns
    {model label: {parameter: spread / sigma, "_mean_z": {parameter: mean z}, "_pooled_rms_z": RMS
    of (estimate - truth) / sigma over all draws and parameters}}.
    ``save``: a JSON-lines file; draws already in it (same seed, jitter, system and model) are
    reused, new ones appended, so a long run can be resumed."""
    import json

    key = (system_name, list(jitter) if jitter else None)
    done = _saved_draws(save, key)
    labels = [model_label(n, s) for n, s in models]
    runs = {label: [] for label in labels}
    for k in range(draws):
        seed = 100 + k
        if all((seed, label) in done for label in labels):
            for label in labels:
                runs[label].append(done[(seed, label)])
            continue
        obs, n_images, seconds = observe_session(truth_system, work, seed=seed, jitter=jitter)
        for (n, s), label in zip(models, labels):
            r = done.get((seed, label)) or fit_session(obs, truth_system, n_dist=n, skew=s)
            if (seed, label) not in done:
                r.update(seed=seed, jitter=key[1], system=system_name, seconds=seconds)
                if save is not None:
                    with open(save, "a") as f:
                        f.write(json.dumps(r) + "\n")
            runs[label].append(r)
            print(f"draw {k + 1}/{draws} [{label}]: max |z| {r['max_z']:.2f}, RMS cam/prj "
                  f"{r['rms']['camera']:.4f}/{r['rms']['projector']:.4f} px", file=sys.stderr, flush=True)
    what = ("sensor noise and board poses (jitter: rotation <= %g deg, translation <= %g mm per pose)" % tuple(jitter)
            if jitter else "sensor noise only (same board poses)")
    lo, hi = spread_interval(draws)
    results = {}
    for label in labels:
        print(f"\n### Spread over {draws} repeated sessions vs the predicted sigma: truth "
              f"{truth_system.meta.get('name', system_name)}, model {label} ({what})\n", file=out)
        results[label] = _print_spread(runs[label], draws, lo, hi, out)
    return results


def _print_spread(runs, draws, lo, hi, out) -> dict:
    print(f"With {draws} draws, spread / sigma of a correctly predicted sigma lies in [{lo:.2f}, {hi:.2f}] "
          "with 90 % probability (chi distribution); the mean z of an unbiased estimate lies within "
          f"+-{1.645 / np.sqrt(draws):.2f}.\n", file=out)
    print("| parameter | true | mean estimate | spread (std over draws) | mean predicted sigma | spread / sigma |"
          " mean z | RMS z | draws within 3 sigma |", file=out)
    print("|---|---|---|---|---|---|---|---|---|", file=out)
    result, mean_z, all_z, basic_z = {}, {}, [], []
    for key in runs[0]["est"]:
        est = np.array([r["est"][key] for r in runs])
        sig = np.array([r["std"][key] for r in runs])
        true = runs[0]["true"][key]
        z = (est - true) / sig
        all_z.append(z)
        if key.split(".")[1] in ("fx", "fy", "cx", "cy"):
            basic_z.append(z)
        spread = float(np.std(est, ddof=1))
        result[key] = spread / float(np.mean(sig))
        mean_z[key] = float(z.mean())
        print(f"| {key} | {true:.6g} | {est.mean():.6g} | {spread:.3g} | {sig.mean():.3g} | {result[key]:.2f} | "
              f"{z.mean():+.2f} | {np.sqrt(np.mean(z ** 2)):.2f} | {int(np.sum(np.abs(z) <= 3))}/{draws} |",
              file=out, flush=True)
    all_z, basic_z = np.concatenate(all_z), np.concatenate(basic_z)
    result["_mean_z"] = mean_z
    result["_pooled_rms_z"] = float(np.sqrt(np.mean(all_z ** 2)))
    rms_cam = np.mean([r["rms"]["camera"] for r in runs])
    rms_prj = np.mean([r["rms"]["projector"] for r in runs])
    print(f"\nPooled over the {len(mean_z)} parameters and {draws} draws: RMS z {result['_pooled_rms_z']:.2f} "
          f"(1 = the predicted sigma is the actual error), {int(np.sum(np.abs(all_z) <= 3))}/{all_z.size} "
          f"within 3 sigma; over fx fy cx cy of both devices RMS z {np.sqrt(np.mean(basic_z ** 2)):.2f}. "
          f"Mean reprojection RMS camera {rms_cam:.4f} px, projector {rms_prj:.4f} px.", file=out, flush=True)
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=10, help="noise draws of the spread table (default 10)")
    ap.add_argument("--only", choices=("cost", "spread"), help="run one table only")
    ap.add_argument("--save", metavar="JSONL", help="keep every draw in this file and reuse it when run again")
    ap.add_argument("--jitter", type=float, nargs=2, default=(1.0, 5.0), metavar=("DEG", "MM"),
                    help="per-draw random board pose perturbation (default 1 deg, 5 mm; 0 0: noise only)")
    ap.add_argument("--system", choices=SYSTEMS, default="twin",
                    help="the rendered truth: twin (no skew or distortion; default), real (built-in: distorted, "
                         "skewed), real-noskew (distorted, skew 0)")
    ap.add_argument("--distortion", type=int, nargs="+", choices=(0, 4, 5, 8, 12), default=[5],
                    help="distortion terms of the spread table's model(s) (default 5)")
    ap.add_argument("--skew", choices=("fixed", "estimated", "both"), default="fixed",
                    help="skew of the spread table's model(s): fixed at 0 (default, as calib run), estimated, both")
    ap.add_argument("--quick", action="store_true", help="the paper's session only in the cost table, 2 draws")
    args = ap.parse_args(argv)
    draws = 2 if args.quick else args.draws
    if draws < 2:
        ap.error(f"--draws: need at least 2 draws for a spread, got {draws}")
    truth = truth_system(args.system)
    skews = {"fixed": (False,), "estimated": (True,), "both": (False, True)}[args.skew]
    models = tuple((n, s) for s in skews for n in args.distortion)
    with tempfile.TemporaryDirectory(prefix="sltwin-bench-") as tmp:
        work = Path(tmp)
        if args.only in (None, "cost"):
            cost_table(truth, work, quick=args.quick)
        if args.only in (None, "spread"):
            spread_table(truth, work, draws, jitter=tuple(args.jitter) if any(args.jitter) else None,
                         save=args.save, models=models, system_name=args.system)
    print("\n(2-core CPU; times are wall-clock seconds of this run)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
