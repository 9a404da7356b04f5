"""``calib report``: the twin-equivalence report (HTML with embedded figures + Markdown)."""
from __future__ import annotations


def add_arguments(p) -> None:
    p.add_argument("--real", nargs="+", required=True, metavar="FILE",
                   help="real calibration: calibration.json, or a Bouguet .mat pair (camera, projector)")
    p.add_argument("--twin", nargs="+", required=True, metavar="FILE",
                   help="twin calibration: calibration.json, or a Bouguet .mat pair (camera, projector)")
    p.add_argument("-o", "--output", default="report", help="output folder (default: %(default)s)")


def run(args) -> int:
    from .twin_report import write_twin_report

    summary = write_twin_report(args.real, args.twin, args.output)
    print(f"wrote {summary['paths']['html']} and {summary['paths']['md']}")
    flagged = summary["beyond_3_sigma"]
    print("parameters beyond 3 sigma: " + (", ".join(flagged) if flagged else "none"))
    return 0
