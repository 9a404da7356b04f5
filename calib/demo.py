"""``calib demo``: the main job on the built-in default system, from images to the report.

1. the paper's real system -> its digital twin (``calib twin``; table S3 beside ours): twin.json +
   Blender script;
2. the paper's calibration session rendered inside the twin (``calib render-board``): the 9x11
   circle board (20 mm) at 9 poses tilted (0 +-10, 0 +-20, 0) deg, vertical and horizontal fringes,
   12 steps at 1, 8, 48 periods, plus a white frame, with sensor noise, in the DESIGN.md layout;
3. ``calib run`` on those images: unwrapping, board detection, projector pixels from the phase,
   Zhang seeds and the joint casadi bundle adjustment; the estimates against the twin's exactly
   known parameters in units of their predicted standard deviations;
4. ``calib report``: real vs twin-calibrated, with the ball cross-reconstruction (the twin ball
   rendered by synth at the real ball's fitted pose) when the paper's data are beside the
   repository (../shared/data/dp-tpu).

The twin is what Blender can represent: the real calibration without skew and distortion.
"""
from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", default="out/demo", help="output folder (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="noise seed of the simulated session")
    p.add_argument("--data", default=None, help="folder of the paper's dp-tpu data (default: ../shared/data/dp-tpu "
                                                 "beside the repository, when present)")


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

    from .bundle_adjustment import BAConfig
    from .calibrate import run_calibration
    from .calibration_report import write_outputs
    from .io.calibration_json import write_calibration_json
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

    print("\n== [2/4] the paper's calibration session rendered in the twin (calib render-board)", flush=True)
    from synth.board_session import render_board_session
    from synth.boards import BoardSpec

    cap_dir = out / "captures"
    if cap_dir.exists():
        shutil.rmtree(cap_dir)
    truth = render_board_session(cap_dir, true_twin, steps=12, frequencies=(1, 8, 48), n_poses=9, seed=args.seed,
                                 board=BoardSpec(), progress=lambda m: print("   " + m, flush=True))
    n_images = sum(1 for _ in cap_dir.glob("pose_*/*.png"))
    print(f"   {n_images} images in {cap_dir}", flush=True)

    print("\n== [3/4] calib run on the images: unwrap, detect, phase fit, Zhang, joint casadi bundle adjustment",
          flush=True)
    from .capture_outputs import write_capture_outputs
    from .captures import observations_from_captures

    say = lambda m: print("   " + m, flush=True)   # noqa: E731
    captured = observations_from_captures(cap_dir, keep_images=True, progress=say)
    obs = captured.observations
    cal = run_calibration(obs, BAConfig(progress=say))
    cal_dir = out / "twin_calibration"
    write_outputs(cal, obs, cal_dir, extra={"captures": captured.summary()})
    write_capture_outputs(captured, cal_dir)
    lines, beyond = truth_table(true_twin, cal.system, cal.ba.std)
    print("\n".join("   " + line for line in lines))
    print(f"   {8 - beyond} of 8 intrinsics within the predicted 3 sigma of the twin's true values "
          f"({len(truth['board_poses'])} poses, {obs.count('camera')} camera / {obs.count('projector')} projector "
          "points)", flush=True)

    print("\n== [4/4] calib report: real vs twin-calibrated", flush=True)
    data = Path(args.data) if args.data else Path(__file__).resolve().parents[2] / "shared" / "data" / "dp-tpu"
    if (data / "CamCalibResult_real.mat").exists():
        real_inputs = [data / "CamCalibResult_real.mat", data / "PrjCalibResult_real.mat"]
        phases = {"real": data / "standardball_phase_real.mat"}
    else:
        print(f"   (no paper data at {data}: the real side is the built-in calibration, without observations)")
        real_inputs = [write_calibration_json(real, out / "real_calibration.json")]
        phases = {}
    summary = write_twin_report(real_inputs, [cal_dir / "calibration.json"], out / "report", phases=phases,
                                twin_render_system=true_twin)
    print("\n   real (S2) vs twin-calibrated (S4 in the paper), intrinsics:")
    print(f"   {'parameter':16} {'real':>11} {'twin-calibrated':>16} {'difference':>11}")
    for kind in ("camera", "projector"):
        r, e = getattr(real, kind), getattr(cal.system, kind)
        for p in ("fx", "fy", "cx", "cy"):
            print(f"   {kind + '.' + p:16} {getattr(r, p):11.3f} {getattr(e, p):16.3f} "
                  f"{getattr(e, p) - getattr(r, p):11.3f}")
    rows = {}
    for r in summary.get("sphere_matrix", []):
        cell = rows.setdefault((r["phase"], r["calibration"]), {"paper": r.get("paper_um")})
        cell[r["method"]] = r["rms_um"]
    if rows:
        print("\n   ball sphere-fit RMS (um), the paper's Fig. 3 with the real ball and our twin render:")
        print(f"   {'phase':44} {'calibration':34} {'linear':>8} {'ours':>8} {'paper':>8}")
        for (phase, calib_name), cell in rows.items():
            paper = f"{cell['paper']:8.3f}" if cell.get("paper") else f"{'':8}"
            print(f"   {phase:44} {calib_name:34} {cell.get('linear', float('nan')):8.2f} "
                  f"{cell.get('distortion-aware', float('nan')):8.2f} {paper}")
        print("   (linear: the paper's K[R|T] triangulation; ours: distortion-aware triangulation)")
    print(f"   report: {summary['paths']['html']}")
    print(f"\ndemo done in {time.perf_counter() - t0:.1f} s; outputs in {out}/")
    return 0
