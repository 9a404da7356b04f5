"""``calib report``: the twin-equivalence report (HTML with embedded figures + Markdown)."""
from __future__ import annotations

import argparse

from ..errors import CommandError
from ..outputs import claim

from ..argtypes import positive_float

HELP = "twin-equivalence report (HTML + Markdown)"


def add_arguments(p) -> None:
    p.add_argument("--real", nargs="+", required=True, metavar="FILE",
                   help="real calibration: calibration.json, or a Bouguet .mat pair (camera, projector)")
    p.add_argument("--twin", nargs="+", required=True, metavar="FILE",
                   help="twin calibration: calibration.json, or a Bouguet .mat pair (camera, projector)")
    p.add_argument("--phase-real", metavar="FILE", help="real absolute phase map (.mat/.npy/.h5), vertical fringes")
    p.add_argument("--phase-twin", metavar="FILE", help="twin absolute phase map of the same object")
    p.add_argument("--frequency", type=positive_float, default=96.0,
                   help="periods across the projector of the phase maps")
    p.add_argument("--twin-ball-render", action=argparse.BooleanOptionalAction, default=None,
                   help="render the twin ball phase with synth at the real ball's fitted pose and add it to the "
                        "Fig. 3 matrix (default: on when --phase-real is given without --phase-twin)")
    p.add_argument("--ball-frequencies", type=positive_float, nargs="+", default=None, metavar="F",
                   help="fringe ladder of the twin ball render, ending at --frequency (default: 1 8 96)")
    p.add_argument("--twin-ball-system", choices=("ideal", "real"), default="ideal",
                   help="system that renders the twin ball: the real calibration without skew and distortion "
                        "(ideal, what the Blender twin represents; default) or with them (real)")
    p.add_argument("--ball-noise", default="match", metavar="match|none|SIGMA",
                   help="twin ball sensor noise: match the real phase noise (default), none, or a phase noise in rad")
    p.add_argument("--learned-real", nargs="+", default=[], metavar="FILE",
                   help="real capture dataset(s) with reference orders (calib export --capture): adds the learned "
                        "unwrapping's twin-vs-real section")
    p.add_argument("--learned-twin", nargs="+", default=[], metavar="FILE",
                   help="twin renders of the same system with matched noise (experiments.learned_parity)")
    p.add_argument("--learned-model", default="learned", metavar="learned|PATH",
                   help="model of that section (default: the shipped one)")
    p.add_argument("-o", "--output", default="report", help="output folder (default: %(default)s)")


def ball_options(args) -> dict:
    """Keyword arguments of the twin ball render from ``--ball-frequencies`` / ``--ball-noise``."""
    opts = {}
    if args.ball_frequencies:
        opts["frequencies"] = args.ball_frequencies
    if args.ball_noise != "match":
        try:
            opts["noise"] = None if args.ball_noise == "none" else float(args.ball_noise)
        except ValueError:
            raise CommandError(f"--ball-noise: expected match, none or a number (rad), got {args.ball_noise!r}") from None
    return opts


def print_summary(summary: dict) -> None:
    """What ``calib report`` prints: the files, the flagged parameters, the twin ball and the matrix."""
    print(f"wrote {summary['paths']['html']} and {summary['paths']['md']}")
    flagged = summary["beyond_3_sigma"]
    print("parameters beyond 3 sigma: " + (", ".join(flagged) if flagged else "none"))
    if summary.get("expected_differences"):
        print("differences the twin has by design (no skew or lens distortion in Blender): "
              + ", ".join(summary["expected_differences"]))
    ball = summary.get("twin_ball")
    if ball:
        p = ball["pose"]
        print(f"twin ball: centre {' '.join(f'{v:.3f}' for v in p['centre_cam_mm'])} mm (camera frame), radius "
              f"{p['radius_mm']:.3f} mm; footprint IoU {ball['footprint']['iou']:.3f}; floor "
              f"{ball['floor']['render_and_decode']['distortion_aware_um']:.2g} um (render + decode, "
              f"distortion-aware); phase in {ball['file']}")
    for r in summary.get("sphere_matrix", []):
        paper = f" (paper {r['paper_um']:.3f})" if r.get("paper_um") else ""
        print(f"sphere RMS, {r['phase']} phase + {r['calibration']} calibration, {r['method']}: "
              f"{r['rms_um']:.4g} um{paper}")


def run(args) -> int:
    from experiments.twin_ball import twin_ball_for_report
    from reports.twin_report import write_twin_report

    claim(args.output, "dir", inputs=[*args.real, *args.twin, args.phase_real, args.phase_twin, *args.learned_real,
                                        *args.learned_twin])
    opts = ball_options(args)
    extra, parity = [], None
    if args.learned_real or args.learned_twin:
        if not (args.learned_real and args.learned_twin):
            raise CommandError("--learned-real and --learned-twin go together")
        from experiments.learned_parity import parity as learned_parity
        from reports.learned_parity import section

        from ..inputs import dataset_files, model_of_kind

        dataset_files(args.learned_real, "--learned-real", need_reference=True,
                      needs="a real capture exported with its reference orders: calib export --capture DIR -o real.h5")
        dataset_files(args.learned_twin, "--learned-twin",
                      needs="twin renders of the same system: calib export CONFIG -o twin.h5")
        model_of_kind(args.learned_model, "physics", "--learned-model")

        sec, parity = section(learned_parity(args.learned_real, args.learned_twin, args.learned_model))
        extra.append(sec)
    phases = {k: v for k, v in (("real", args.phase_real), ("twin", args.phase_twin)) if v}
    ball = twin_ball_for_report(args.real, phases, args.output, frequency=args.frequency, render=args.twin_ball_render,
                                render_system="real" if args.twin_ball_system == "real" else None, options=opts)
    summary = write_twin_report(args.real, args.twin, args.output, extra_sections=extra, phases=phases,
                                frequency=args.frequency, twin_ball=ball)
    print_summary(summary)
    if parity is not None:
        print(parity["verdict"])
    return 0
