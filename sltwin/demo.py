"""The main job on the built-in default system, from images to the report (``calib demo``).

1. the paper's real system -> its digital twin (as ``calib twin``; table S3 beside ours):
   ``twin.json`` + Blender script;
2. the paper's calibration session rendered inside the twin (as ``calib render-board``): the 9x11
   circle board (20 mm) at 9 poses tilted (0 +-10, 0 +-20, 0) deg, vertical and horizontal
   fringes, 12 steps at 1, 8, 48 periods, plus a white frame, with sensor noise, in the DESIGN.md
   layout;
3. ``calib run`` on those images (:func:`calib.pipeline.calibrate_captures`): unwrapping, board
   detection, projector pixels from the phase, Zhang seeds and the joint casadi bundle
   adjustment; the estimates against the twin's exactly known parameters in units of their
   predicted standard deviations;
4. ``calib report``: real vs twin-calibrated, with the ball cross-reconstruction (the twin ball
   rendered by synth at the real ball's fitted pose) when the paper's data are beside the
   repository (../shared/data/dp-tpu), and the learned unwrapping's twin-vs-real parity with the
   shipped model (SLStudio's skull capture against twin renders of its system with matched noise,
   when ../shared/data/slstudio-ps2x3-calib is there; experiments.learned_parity).

The twin is what Blender can represent: the real calibration without skew and distortion. Tables
go to stdout, progress to the packages' loggers.

SYNOPSIS

    from sltwin.demo import run_demo
    summary = run_demo("out/demo")       # about a minute; prints the tables as ``calib demo``
"""
from __future__ import annotations

import shutil
import time
from pathlib import Path

from .commands.twin import write_twin

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "dp-tpu"
"""Where the paper's dp-tpu data are looked for (beside the repository)."""


def truth_table(true_system, estimate, std) -> tuple[list[str], int]:
    """Lines of the intrinsics table (true twin value, estimate, predicted sigma, z) and the
    number of parameters beyond 3 sigma."""
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


def make_twin(out: Path):
    """Step 1: the built-in system's twin files; returns the true twin (the ideal pinhole system
    the twin represents, read back from ``twin.json``)."""
    from calib.system import default_system
    from twin_mapping.twin import from_twin, read_twin_json

    print("== [1/4] built-in real system -> digital twin (calib twin)", flush=True)
    write_twin(default_system(), out / "twin.json", out / "twin_scene.py")
    return from_twin(read_twin_json(out / "twin.json")).ideal({"name": "digital twin (ideal pinhole)"})


def render_session(out: Path, true_twin, seed: int) -> tuple[Path, dict]:
    """Step 2: the paper's calibration session rendered in the twin; returns the capture folder
    and the session's truth (``synth.scenes.board_session.render_board_session``)."""
    from synth.scenes.board_session import render_board_session

    print("\n== [2/4] the paper's calibration session rendered in the twin (calib render-board)", flush=True)
    cap_dir = out / "captures"
    if cap_dir.exists():
        shutil.rmtree(cap_dir)
    truth = render_board_session(cap_dir, true_twin, steps=12, frequencies=(1, 8, 48), n_poses=9, seed=seed)
    print(f"   {sum(1 for _ in cap_dir.glob('pose_*/*.png'))} images in {cap_dir}", flush=True)
    return cap_dir, truth


def calibrate_session(cap_dir: Path, cal_dir: Path, true_twin, n_poses: int):
    """Step 3: ``calib run`` on the images, and the estimates against the twin's true values."""
    from calib.pipeline import calibrate_captures

    print("\n== [3/4] calib run on the images: unwrap, detect, phase fit, Zhang, joint casadi bundle adjustment",
          flush=True)
    run = calibrate_captures(cap_dir, cal_dir)
    cal, obs = run.calibration, run.observations
    lines, beyond = truth_table(true_twin, cal.system, cal.ba.std)
    print("\n".join("   " + line for line in lines))
    print(f"   {8 - beyond} of 8 intrinsics within the predicted 3 sigma of the twin's true values "
          f"({n_poses} poses, {obs.count('camera')} camera / {obs.count('projector')} projector "
          "points)", flush=True)
    return run


def print_intrinsics(real, estimate) -> None:
    """The real system's intrinsics beside the twin-calibrated ones (the paper's S2 vs S4)."""
    print("\n   real (S2) vs twin-calibrated (S4 in the paper), intrinsics:")
    print(f"   {'parameter':16} {'real':>11} {'twin-calibrated':>16} {'difference':>11}")
    for kind in ("camera", "projector"):
        r, e = getattr(real, kind), getattr(estimate, kind)
        for p in ("fx", "fy", "cx", "cy"):
            print(f"   {kind + '.' + p:16} {getattr(r, p):11.3f} {getattr(e, p):16.3f} "
                  f"{getattr(e, p) - getattr(r, p):11.3f}")


def print_sphere_matrix(rows) -> None:
    """The paper's Fig. 3 matrix: sphere-fit RMS per (phase, calibration), linear and ours."""
    cells = {}
    for r in rows:
        cell = cells.setdefault((r["phase"], r["calibration"]), {"paper": r.get("paper_um")})
        cell[r["method"]] = r["rms_um"]
    if not cells:
        return
    print("\n   ball sphere-fit RMS (um), the paper's Fig. 3 with the real ball and our twin render:")
    print(f"   {'phase':44} {'calibration':34} {'linear':>8} {'ours':>8} {'paper':>8}")
    for (phase, calib_name), cell in cells.items():
        paper = f"{cell['paper']:8.3f}" if cell.get("paper") else f"{'':8}"
        print(f"   {phase:44} {calib_name:34} {cell.get('linear', float('nan')):8.2f} "
              f"{cell.get('distortion-aware', float('nan')):8.2f} {paper}")
    print("   (linear: the paper's K[R|T] triangulation; ours: distortion-aware triangulation)")


def report(out: Path, cal_dir: Path, true_twin, estimate, data: Path) -> dict:
    """Step 4: ``calib report`` real vs twin-calibrated (with the ball when the paper's data are there)."""
    from calib.io.calibration_json import write_calibration_json
    from calib.system import default_system
    from experiments.twin_ball import twin_ball_for_report
    from reports.twin_report import write_twin_report

    print("\n== [4/4] calib report: real vs twin-calibrated", flush=True)
    real = default_system()
    if (data / "CamCalibResult_real.mat").exists():
        real_inputs = [data / "CamCalibResult_real.mat", data / "PrjCalibResult_real.mat"]
        phases = {"real": data / "standardball_phase_real.mat"}
    else:
        print(f"   (no paper data at {data}: the real side is the built-in calibration, without observations)")
        real_inputs = [write_calibration_json(real, out / "real_calibration.json")]
        phases = {}
    extra, parity = [], None
    if (data.parent / "slstudio-ps2x3-calib").is_dir():
        from experiments.learned_parity import slstudio_parity
        from reports.learned_parity import section

        print("   learned unwrapping: SLStudio skull capture vs its twin with matched noise (shipped model)", flush=True)
        measured = slstudio_parity(data.parent, out / "learned_parity")
        if measured is not None:
            parity = section(measured["parity"], twin_info=measured["twin"])
            extra.append(parity[0])
    ball = twin_ball_for_report(real_inputs, phases, out / "report", render_system=true_twin)
    summary = write_twin_report(real_inputs, [cal_dir / "calibration.json"], out / "report", phases=phases,
                                twin_ball=ball, extra_sections=extra)
    if parity is not None:
        summary["learned_parity"] = parity[1]
        for r in parity[1]["rows"]:
            print(f"   {r['data']:4s} f = {r['f']:g}: traditional {100 * r['traditional']:.3f} %, filtered "
                  f"{100 * r['filtered']:.3f} %, learned {100 * r['learned']:.3f} % ({r['pixels']} pixels)")
        print("   " + parity[1]["verdict"])
    print_intrinsics(real, estimate)
    print_sphere_matrix(summary.get("sphere_matrix", []))
    print(f"   report: {summary['paths']['html']}")
    return summary


def run_demo(out="out/demo", *, seed: int = 0, data=None) -> dict:
    """Run the four steps (module docstring) into ``out``; returns the report summary.

    ``seed``: noise seed of the rendered session; ``data``: folder of the paper's dp-tpu data
    (default: ``DEFAULT_DATA`` when present)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    true_twin = make_twin(out)
    cap_dir, truth = render_session(out, true_twin, seed)
    run = calibrate_session(cap_dir, out / "twin_calibration", true_twin, len(truth["board_poses"]))
    summary = report(out, out / "twin_calibration", true_twin, run.calibration.system,
                     Path(data) if data else DEFAULT_DATA)
    print(f"\ndemo done in {time.perf_counter() - t0:.1f} s; outputs in {out}/")
    return summary
