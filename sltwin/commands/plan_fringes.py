"""``calib plan-fringes``: predicted fringe-order error rate vs number of images (Markdown table)."""
from __future__ import annotations

from ..argtypes import positive_float, probability

HELP = "predicted fringe-order error rate vs number of images"


def add_arguments(parser):
    parser.add_argument("--sigma", type=positive_float, default=2.0,
                        help="intensity noise per frame (grey levels, default 2)")
    parser.add_argument("--modulation", type=positive_float, default=60.0,
                        help="fringe modulation B (grey levels, default 60)")
    parser.add_argument("--steps", type=int, nargs="+", default=[3, 4, 6, 12],
                        help="step counts N to compare (default 3 4 6 12)")
    parser.add_argument("--sets", nargs="+", default=None,
                        help="frequency sets METHOD:F1,F2,... (mf, mw, nt, gray: the names of calib unwrap --method); default: a "
                             "standard list including the paper's mf:1,8,48")
    parser.add_argument("--max-error-rate", type=probability, default=1e-3,
                        help="mark rows above this predicted error rate (default 1e-3)")


def run(args) -> int:
    from unwrap.plan import DEFAULT_SETS, format_table, plan_fringes

    rows = plan_fringes(args.sets or DEFAULT_SETS, args.steps, sigma=args.sigma,
                        modulation=args.modulation)
    print(f"Predicted fringe-order error rate (interior pixels), noise sigma = {args.sigma:g}, "
          f"modulation B = {args.modulation:g}; sigma_phi^2 = 2 sigma^2 / (N B^2)\n")
    print(format_table(rows, args.max_error_rate))
    return 0
