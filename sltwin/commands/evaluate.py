"""``calib eval [--model M] [--prior-free P] [--mse-only S] (--test FILE ... | --synthetic N) [--real FILE ...]
-o OUT``: tables S5 / S6 beside the paper's, confidence curves, real captures, speed
(experiments.learned_eval)."""
from __future__ import annotations

from sltwin.errors import CommandError

HELP = "evaluate learned unwrapping: S5 / S6 layouts with the paper's numbers, real captures, speed"


def add_arguments(parser):
    parser.add_argument("--model", default="learned", help="physics-aware model (checkpoint; default: the shipped one)")
    parser.add_argument("--prior-free", default=None, help="prior-free model (the DT-TPU row of S5)")
    parser.add_argument("--mse-only", default=None, help="physics-aware model trained with MSE only (S6)")
    parser.add_argument("--test", nargs="+", default=[], help="held-out test dataset file(s) (HDF5, unwrap.dataset)")
    parser.add_argument("--synthetic", type=int, default=0, metavar="N",
                        help="instead of --test: N in-memory synthetic scenes (quick check)")
    parser.add_argument("--real", nargs="+", default=[], help="real capture dataset file(s) with reference orders")
    parser.add_argument("--max-samples", type=int, default=None, help="score at most this many test scenes")
    parser.add_argument("--s5", type=float, nargs="+", default=[48, 96], help="S5 frequencies (default 48 96)")
    parser.add_argument("--s6", type=float, nargs="*", default=[16, 32, 48, 64, 80, 96],
                        help="S6 frequencies (default 16 32 48 64 80 96; none to skip)")
    parser.add_argument("--methods", nargs="+", default=["mf", "mw", "nt"], choices=["mf", "mw", "nt"])
    parser.add_argument("--window", type=int, default=15, help="box of the filtered baseline (px)")
    parser.add_argument("--no-speed", action="store_true", help="skip the timing table")
    parser.add_argument("--training-run", nargs="+", default=[], metavar="NAME=RUN",
                        help="run folders whose training samples/s go into the speed table")
    parser.add_argument("-o", "--output", required=True, help="output folder (eval.md, eval.json, figures)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress messages")


def run(args) -> int:
    from experiments.learned_eval import evaluate_models
    from reports.learned_eval import write_evaluation
    from experiments.learned_evaluation import TestSource
    from unwrap.learned.infer import shipped_model_path

    from pathlib import Path

    from ..outputs import output_dir

    if bool(args.test) == bool(args.synthetic):
        raise CommandError("give either --test FILE ... or --synthetic N")
    for f in list(args.test) + list(args.real):
        if not Path(f).is_file():
            raise CommandError(f"{f}: no such dataset file (calib export writes them)")
    output_dir(args.output)
    runs = {}
    for item in args.training_run:
        if "=" not in item:
            raise CommandError(f"--training-run {item!r}: expected NAME=RUN_FOLDER")
        name, run_dir = item.split("=", 1)
        runs[name] = run_dir
    src = TestSource(files=list(args.test), synthetic=(args.synthetic, (96, 128), 9001) if args.synthetic else None,
                     max_samples=args.max_samples)
    physics = shipped_model_path() if args.model in ("learned", "default") else args.model
    res = write_evaluation(evaluate_models(
        src, physics=physics, prior_free=args.prior_free, mse_only=args.mse_only, real=list(args.real),
        s5_frequencies=tuple(args.s5), s6_frequencies=tuple(args.s6), methods=tuple(args.methods),
        filtered_window=args.window, speed=not args.no_speed, training_runs=runs), args.output)
    print(res["markdown"])
    print(f"wrote {args.output}/eval.md, eval.json, {', '.join(res['figures'])}")
    return 0
