"""The outlier rule of the adjustment on the paper's real observations, and what it does to the estimate.

    python -m bench.outlier_rule [--draws 40] [--quick]

1. The paper's own observations (``../shared/data/dp-tpu``, Bouguet results of 9 views, 35
   points each), adjusted jointly without rejection: the distribution of the normalised point
   residuals |e| / sigma per device (sigma per coordinate from the median: the rule's robust
   sigma), the count beyond 3, 4, 5 sigma beside what a Gaussian at that sigma expects
   (``n exp(-t^2/2)``: |e| / sigma is Rayleigh), per view; then the default rule's rejections.
2. Simulation of what the measured residuals look like (the paper's system without skew, which
   the adjustment holds at 0, the same board,
   camera noise 0.06 px, projector noise 0.11 px in 7 views and 0.40 px in 2): the error of the
   projector intrinsics over noise draws, and how well the predicted sigma describes it
   (spread / predicted sigma), for no rejection, the default 5-sigma rule, and per-view noise
   weights (:func:`calib.calibrate.reweight_views`).

Prints Markdown tables.
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "dp-tpu"
PARAMS = ("fx", "fy", "cx", "cy")


def _normalised(cal, device):
    """|e| / sigma_robust of every point of ``device`` (no rejection) and its views."""
    ba = cal.ba
    m = ba.point_device == device
    e = np.linalg.norm(ba.residuals_px[m], axis=1)
    sigma = math.sqrt(np.median(e ** 2) / (2.0 * math.log(2.0)))
    return e / sigma, ba.point_view[m], sigma


def real_data_tables() -> None:
    from calib.adjustment.problem import BAConfig
    from calib.calibrate import run_calibration
    from calib.observations import from_bouguet

    if not (DATA / "CamCalibResult_real.mat").exists():
        print(f"(no real data at {DATA}: part 1 skipped)")
        return
    obs = from_bouguet(DATA / "CamCalibResult_real.mat", DATA / "PrjCalibResult_real.mat")
    cal = run_calibration(obs, BAConfig(outlier_threshold=None))
    print("### The paper's observations, joint adjustment without rejection\n")
    print("| device | points | robust sigma px | 50 % | 90 % | 99 % | max | > 3 sigma (Gaussian) | > 4 sigma (Gaussian) "
          "| > 5 sigma (Gaussian) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for d in ("camera", "projector"):
        z, _, sigma = _normalised(cal, d)
        q = np.quantile(z, [0.5, 0.9, 0.99, 1.0])
        counts = " | ".join(f"{int((z > t).sum())} ({len(z) * math.exp(-t * t / 2):.2g})" for t in (3, 4, 5))
        print(f"| {d} | {len(z)} | {sigma:.4f} | " + " | ".join(f"{v:.2f}" for v in q) + f" | {counts} |")
    print("\n| view | camera RMS / sigma | projector RMS / sigma | projector points > 5 sigma |")
    print("|---:|---:|---:|---:|")
    zc, vc, _ = _normalised(cal, "camera")
    zp, vp, _ = _normalised(cal, "projector")
    for v in np.unique(vp):
        print(f"| {v + 1} | {math.sqrt(np.mean(zc[vc == v] ** 2) / 2):.2f} | {math.sqrt(np.mean(zp[vp == v] ** 2) / 2):.2f} "
              f"| {int((zp[vp == v] > 5).sum())} |")
    ruled = run_calibration(obs, BAConfig())
    per_view = {}
    for r in ruled.ba.rejected:
        per_view.setdefault(r["device"], []).append(r["view"] + 1)
    print("\nDefault rule (reject beyond 5 robust sigma, iterated): "
          + "; ".join(f"{d}: {len(v)} rejected, in views {sorted(set(v))}" for d, v in sorted(per_view.items())))


def _noisy_observations(system, board, rng, noise_cam, noise_prj, noisy_views, noise_noisy):
    from calib.observations import Observations, ViewObservations
    from calib.simulate import simulate_observations

    clean, _ = simulate_observations(system, board, 9, 0.0, rng)
    views = []
    for i, v in enumerate(clean.views):
        s_prj = noise_noisy if i in noisy_views else noise_prj
        q = {"camera": v.q["camera"] + rng.normal(0, noise_cam, v.q["camera"].shape),
             "projector": v.q["projector"] + rng.normal(0, s_prj, v.q["projector"].shape)}
        views.append(ViewObservations(v.points_board, q, dict(v.sigma), name=v.name))
    return Observations(views, clean.sizes, source="simulated")


def _without_skew(system):
    from calib.system import SystemModel

    devices = []
    for d in (system.camera, system.projector):
        K = np.array(d.K)
        K[0, 1] = 0.0
        devices.append(d.with_(K=K))
    return SystemModel(*devices, dict(system.meta))


def simulation_table(draws: int) -> None:
    from calib import default_system
    from calib.board import Board
    from calib.adjustment.problem import BAConfig
    from calib.calibrate import reweight_views, run_calibration

    system = _without_skew(default_system())   # the adjustment holds skew at 0: no model error
    board = Board("checkerboard", 5, 7, 20.0)
    rules = {"no rejection": lambda o: run_calibration(o, BAConfig(outlier_threshold=None)),
             "5 sigma rule (default)": lambda o: run_calibration(o, BAConfig()),
             "per-view noise + 5 sigma rule": lambda o: reweight_views(o, BAConfig())}
    errors = {r: {p: [] for p in PARAMS} for r in rules}
    sigmas = {r: {p: [] for p in PARAMS} for r in rules}
    rejected = {r: [] for r in rules}
    for k in range(draws):
        obs = _noisy_observations(system, board, np.random.default_rng(100 + k), 0.06, 0.11, (0, 1), 0.40)
        for name, fit in rules.items():
            cal = fit(obs)
            for p in PARAMS:
                errors[name][p].append(getattr(cal.system.projector, p) - getattr(system.projector, p))
                sigmas[name][p].append(cal.ba.std[f"projector.{p}"])
            rejected[name].append(sum(r["device"] == "projector" for r in cal.ba.rejected))
    print(f"\n### Simulated: projector noise 0.11 px in 7 views, 0.40 px in 2; {draws} draws\n")
    print("| rule | projector points rejected (mean) | " + " | ".join(f"RMS error {p} px" for p in PARAMS)
          + " | " + " | ".join(f"RMS error / mean predicted sigma, {p}" for p in PARAMS) + " |")
    print("|---|---:|" + "---:|" * (2 * len(PARAMS)))
    for name in rules:
        rms = [math.sqrt(np.mean(np.square(errors[name][p]))) for p in PARAMS]
        ratio = [r / np.mean(sigmas[name][p]) for r, p in zip(rms, PARAMS)]
        print(f"| {name} | {np.mean(rejected[name]):.1f} | " + " | ".join(f"{v:.3f}" for v in rms) + " | "
              + " | ".join(f"{v:.2f}" for v in ratio) + " |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=40)
    ap.add_argument("--quick", action="store_true", help="3 draws")
    args = ap.parse_args(argv)
    real_data_tables()
    simulation_table(3 if args.quick else args.draws)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
