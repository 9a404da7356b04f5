"""``calib report``: the twin-equivalence report (HTML with embedded figures + Markdown)."""
from __future__ import annotations


def add_arguments(p) -> None:
    p.add_argument("--real", nargs="+", required=True, metavar="FILE",
                   help="real calibration: calibration.json, or a Bouguet .mat pair (camera, projector)")
    p.add_argument("--twin", nargs="+", required=True, metavar="FILE",
                   help="twin calibration: calibration.json, or a Bouguet .mat pair (camera, projector)")
    p.add_argument("--phase-real", metavar="FILE", help="real absolute phase map (.mat/.npy/.h5), vertical fringes")
    p.add_argument("--phase-twin", metavar="FILE", help="twin absolute phase map of the same object")
    p.add_argument("--frequency", type=float, default=96.0, help="periods across the projector of the phase maps")
    p.add_argument("-o", "--output", default="report", help="output folder (default: %(default)s)")


def run(args) -> int:
    from .twin_report import write_twin_report

    summary = write_twin_report(args.real, args.twin, args.output, phases={
        k: v for k, v in (("real", args.phase_real), ("twin", args.phase_twin)) if v}, frequency=args.frequency)
    print(f"wrote {summary['paths']['html']} and {summary['paths']['md']}")
    flagged = summary["beyond_3_sigma"]
    print("parameters beyond 3 sigma: " + (", ".join(flagged) if flagged else "none"))
    for r in summary.get("sphere_matrix", []):
        paper = f" (paper {r['paper_um']:.3f})" if r.get("paper_um") else ""
        print(f"sphere RMS, {r['phase']} phase + {r['calibration']} calibration, {r['method']}: "
              f"{r['rms_um']:.2f} um{paper}")
    return 0
