"""What accuracy costs: calibration uncertainty vs number of views and lens model, and solve time vs mrcal.

    python -m bench.calib_accuracy [--draws 3] [--quick]

Synthetic observations of the paper's system (``calib.default_system()``), 5 x 7 board at 20 mm
(as the paper's), camera noise 0.06 px and projector noise 0.2 px (the paper's residuals).
For 3, 5, 9, 15 views and 0/4/5 distortion terms: predicted std of camera fx and projector fy,
their spread over noise draws, reprojection RMS, and time (seed + build + solve). Then the same
camera-only problem solved by our casadi adjustment and by mrcal.optimize (regularisation off):
solve times side by side. Prints Markdown tables.
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def main(argv=None):
    from calib import default_system
    from calib.board import Board
    from calib.adjustment.problem import BAConfig, DeviceConfig
    from calib.calibrate import run_calibration
    from calib.adjustment.mrcal_reference import mrcal_calibrate
    from calib.rotation import matrix_from_rotvec
    from calib.simulate import simulate_observations

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="2 draws, 5 and 9 views, 0 and 5 distortion terms")
    args = ap.parse_args(argv)
    draws = 2 if args.quick else args.draws
    view_counts = (5, 9) if args.quick else (3, 5, 9, 15)
    dist_counts = (0, 5) if args.quick else (0, 4, 5)
    system = default_system()
    board = Board("checkerboard", 5, 7, 20.0)
    print("| views | dist terms | std cam fx (pred) | spread cam fx | std prj fy (pred) | spread prj fy |"
          " RMS cam px | RMS prj px | time s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for n_dist in dist_counts:
        for n_views in view_counts:
            fx, fy, sfx, sfy, rc, rp, tt = [], [], [], [], [], [], []
            for k in range(draws):
                obs, _ = simulate_observations(system, board, n_views, 0.06, np.random.default_rng(100 + k),
                                               noise_prj_px=0.2)
                t0 = time.perf_counter()
                try:
                    cal = run_calibration(obs, BAConfig(camera=DeviceConfig(n_dist), projector=DeviceConfig(n_dist),
                                                        outlier_threshold=None))
                except ValueError as exc:
                    print(f"| {n_views} | {n_dist} | refused: {exc} |")
                    break
                tt.append(time.perf_counter() - t0)
                fx.append(cal.system.camera.fx)
                fy.append(cal.system.projector.fy)
                sfx.append(cal.ba.std["camera.fx"])
                sfy.append(cal.ba.std["projector.fy"])
                rc.append(cal.ba.stats["camera"]["rms_px"])
                rp.append(cal.ba.stats["projector"]["rms_px"])
            if tt:
                spread = lambda a: f"{np.std(a, ddof=1):.3g}" if len(a) > 1 else "-"  # noqa: E731
                print(f"| {n_views} | {n_dist} | {np.mean(sfx):.3g} | {spread(fx)} | {np.mean(sfy):.3g} | "
                      f"{spread(fy)} | {np.mean(rc):.4f} | {np.mean(rp):.4f} | {np.mean(tt):.3f} |")
    print()
    print("| views | dist terms | ours: build s | ours: solve s | mrcal.optimize s | max rel. diff of intrinsics |")
    print("|---|---|---|---|---|---|")
    for n_views in (9,) if args.quick else (5, 9, 15):
        for n_dist in (5,) if args.quick else (4, 5):
            obs, _ = simulate_observations(system, board, n_views, 0.06, np.random.default_rng(7))
            obs = obs.only("camera")
            cal = run_calibration(obs, BAConfig(mode="single", camera=DeviceConfig(n_dist), outlier_threshold=None))
            s = cal.seeds["camera"]
            poses = [(matrix_from_rotvec(r), t) for r, t in zip(s.rvec_dev_board, s.t_dev_board)]
            theirs, _, t_m = mrcal_calibrate(obs, "camera", n_dist, s.K, s.distortion, poses)
            d = cal.system.camera
            ours = np.r_[d.fx, d.fy, d.cx, d.cy, d.distortion]
            rel = np.max(np.abs(ours - theirs) / np.abs(theirs))
            print(f"| {n_views} | {n_dist} | {cal.timings['build_s']:.3f} | {cal.timings['solve_s']:.3f} | "
                  f"{t_m:.4f} | {rel:.1e} |")


if __name__ == "__main__":
    main()
