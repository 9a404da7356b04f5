"""``calib demo``: the main job on the built-in default system.

1. the paper's real system -> its digital twin (table S3 beside ours): twin.json + Blender script;
2. a calibration session of the paper inside the twin (board 9 x 11 circles, 20 mm; 9 poses tilted
   (0 +-10, 0 +-20, 0) deg), at the level of board-point observations with the real system's
   measured noise (Bouguet err_std: camera 0.060 px, projector 0.197 px);
3. ``calib run`` (joint casadi bundle adjustment) on it, and the estimates against the twin's
   exactly known parameters in units of their predicted standard deviations;
4. ``calib report`` real vs twin-calibrated, with the ball reconstruction when the paper's data are
   beside the repository (../shared/data/dp-tpu).

The twin is what Blender can represent: the real calibration without skew and distortion.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

PAPER_BOARD = dict(kind="circles", rows=9, cols=11, spacing_mm=20.0, large_diameter_mm=5.0, small_diameter_mm=2.0,
                   large_markers=((4, 5), (4, 6), (4, 7), (3, 5), (2, 5)))
NOISE_PX = {"camera": 0.0599, "projector": 0.1973}   # dp-tpu *_real.mat err_std, mean of x and y


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", default="out/demo", help="output folder (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="noise seed of the simulated session")
    p.add_argument("--data", default=None, help="folder of the paper's dp-tpu data (default: ../shared/data/dp-tpu "
                                                 "beside the repository, when present)")


def paper_session_poses():
    """The paper's 9 board poses: tilts (0 +-10 deg about x, 0 +-20 deg about y, 0), world = pose 1."""
    from .rotation import matrix_from_rotvec

    poses = []
    for ax in (0.0, -10.0, 10.0):
        for ay in (0.0, -20.0, 20.0):
            R = matrix_from_rotvec([np.radians(ax), 0, 0]) @ matrix_from_rotvec([0, np.radians(ay), 0])
            poses.append((R, np.zeros(3)))
    return poses


def truth_table(true_system, estimate, std) -> tuple[list[str], int]:
    lines = [f"{'parameter':18} {'true (twin)':>12} {'estimate':>12} {'sigma':>9} {'z':>7}"]
    beyond = 0
    for kind in ("camera", "projector"):
        t, e = getattr(true_system, kind), getattr(estimate, kind)
        for p in ("fx", "fy", "cx", "cy"):
            s = std.get(f"{kind}.{p}", float("nan"))
            z = (getattr(e, p) - getattr(t, p)) / s
            beyond += abs(z) > 3
            lines.append(f"{kind + '.' + p:18} {getattr(t, p):12.3f} {getattr(e, p):12.3f} {s:9.3f} {z:7.2f}")
    return lines, beyond


def run(args) -> int:
    from reports.twin_report import write_twin_report
    from twin_mapping import cli as twin_cli
    from twin_mapping.twin import from_twin, read_twin_json

    from .board import Board
    from .bundle_adjustment import BAConfig
    from .calibrate import run_calibration
    from .calibration_report import write_outputs
    from .io.calibration_json import write_calibration_json
    from .observations import write_observations_json
    from .simulate import simulate_observations
    from .system import SystemModel, default_system

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    print("== [1/4] built-in real system -> digital twin (calib twin)", flush=True)
    twin_cli.run(argparse.Namespace(calibration=[], output=str(out / "twin.json"),
                                    blender_script=str(out / "twin_scene.py"), blender=False, repair_rotation=False,
                                    camera_size=None, projector_size=None, paper="auto"))
    real = default_system()
    twin_full = from_twin(read_twin_json(out / "twin.json"))
    true_twin = SystemModel(twin_full.camera.without_skew_and_distortion(),
                            twin_full.projector.without_skew_and_distortion(), {"name": "digital twin (ideal pinhole)"})

    print("\n== [2/4] the paper's calibration session inside the twin (9 poses, board 9x11 circles, 20 mm)", flush=True)
    board = Board(**PAPER_BOARD)
    obs, _ = simulate_observations(true_twin, board, 9, NOISE_PX["camera"], np.random.default_rng(args.seed),
                                   poses=paper_session_poses(), noise_prj_px=NOISE_PX["projector"])
    print(f"   {obs.count('camera')} camera and {obs.count('projector')} projector observations, "
          f"noise {NOISE_PX['camera']} / {NOISE_PX['projector']} px", flush=True)

    print("\n== [3/4] calib run: Zhang seeding + joint casadi bundle adjustment", flush=True)
    cal = run_calibration(obs, BAConfig(progress=lambda m: print("   " + m, flush=True)))
    cal_dir = out / "twin_calibration"
    write_outputs(cal, obs, cal_dir)
    write_observations_json(obs, cal_dir / "observations.json")
    lines, beyond = truth_table(true_twin, cal.system, cal.ba.std)
    print("\n".join("   " + line for line in lines))
    print(f"   {8 - beyond} of 8 intrinsics within the predicted 3 sigma of the twin's true values", flush=True)

    print("\n== [4/4] calib report: real vs twin-calibrated", flush=True)
    data = Path(args.data) if args.data else Path(__file__).resolve().parents[2] / "shared" / "data" / "dp-tpu"
    if (data / "CamCalibResult_real.mat").exists():
        real_inputs = [data / "CamCalibResult_real.mat", data / "PrjCalibResult_real.mat"]
        phases = {"real": data / "standardball_phase_real.mat"}
    else:
        print(f"   (no paper data at {data}: the real side is the built-in calibration, without observations)")
        real_inputs = [write_calibration_json(real, out / "real_calibration.json")]
        phases = {}
    summary = write_twin_report(real_inputs, [cal_dir / "calibration.json"], out / "report", phases=phases)
    for r in summary.get("sphere_matrix", []):
        paper = f" (paper {r['paper_um']:.3f})" if r.get("paper_um") else ""
        print(f"   ball sphere-fit RMS, {r['phase']} phase + {r['calibration']} calibration, {r['method']}: "
              f"{r['rms_um']:.2f} um{paper}")
    print(f"   report: {summary['paths']['html']}")
    print(f"\ndemo done in {time.perf_counter() - t0:.1f} s; outputs in {out}/")
    return 0
