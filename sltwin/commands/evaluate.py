"""``calib eval [--model M] [--prior-free P] [--mse-only S] (--test FILE ... | --synthetic N) [--real FILE ...] [--cycles FILE ...]
-o OUT``: tables S5 / S6 beside the paper's, confidence curves, real captures, speed
(experiments.learned_eval)."""
from __future__ import annotations

from sltwin.errors import CommandError

from ..argtypes import positive_float, positive_int

HELP = "evaluate learned unwrapping: S5 / S6 layouts with the paper's numbers, real captures, speed"


def add_arguments(parser):
    parser.add_argument("--model", default="learned", help="physics-aware model (checkpoint; default: the shipped one)")
    parser.add_argument("--prior-free", default=None, help="prior-free model (the DT-TPU row of S5)")
    parser.add_argument("--mse-only", default=None, help="physics-aware model trained with MSE only (S6)")
    parser.add_argument("--test", nargs="+", default=[], help="held-out test dataset file(s) (HDF5, unwrap.dataset)")
    parser.add_argument("--synthetic", type=positive_int, default=0, metavar="N",
                        help="instead of --test: N in-memory synthetic scenes (quick check)")
    parser.add_argument("--real", nargs="+", default=[], help="real capture dataset file(s) with reference orders")
    parser.add_argument("--cycles", nargs="+", default=[],
                        help="Cycles test set file(s) (python -m bench.cycles_testset): its own section, MF rows at "
                             "the --s5 frequencies")
    parser.add_argument("--max-samples", type=positive_int, default=None,
                        help="score at most this many test scenes (>= 1)")
    parser.add_argument("--s5", type=positive_float, nargs="+", default=[48, 96], metavar="F",
                        help="S5 frequencies, > 1 (default 48 96)")
    parser.add_argument("--s6", type=positive_float, nargs="*", default=[16, 32, 48, 64, 80, 96], metavar="F",
                        help="S6 frequencies, > 1 (default 16 32 48 64 80 96; --s6 with no frequency skips S6)")
    parser.add_argument("--methods", nargs="+", default=["mf", "mw", "nt"], choices=["mf", "mw", "nt"])
    parser.add_argument("--window", type=positive_int, default=15,
                        help="box of the filtered baseline (px, >= 1; default 15)")
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

    from ..inputs import dataset_files, model_of_kind, run_folder
    from ..outputs import claim

    if bool(args.test) == bool(args.synthetic):
        raise CommandError("give either --test FILE ... or --synthetic N")
    for f in list(args.test) + list(args.real) + list(args.cycles):
        if not Path(f).is_file():
            raise CommandError(f"{f}: no such dataset file (calib export writes them)")
    claim(args.output, "dir", inputs=[*args.test, *args.real, *args.cycles, args.model, args.prior_free, args.mse_only])
    for option, freqs in (("--s5", args.s5), ("--s6", args.s6)):
        low = [f for f in freqs if f <= 1]
        if low:
            raise CommandError(f"{option} {low[0]:g}: the unit frequency is the low one of every pair; give "
                               "frequencies > 1")
    dataset_files(args.test, "--test", needs="a fringe-order dataset written by calib export CONFIG (the twin's "
                                              "test data)")
    dataset_files(args.cycles, "--cycles", needs="a Cycles test set written by python -m bench.cycles_testset")
    dataset_files(args.real, "--real", need_reference=True,
                  needs="a real capture with reference orders: calib export --capture DIR -o real.h5")
    model_of_kind(args.model, "physics", "--model")
    if args.prior_free:
        model_of_kind(args.prior_free, "prior_free", "--prior-free")
    if args.mse_only:
        model_of_kind(args.mse_only, "physics", "--mse-only")
    runs = {}
    for item in args.training_run:
        if "=" not in item:
            raise CommandError(f"--training-run {item!r}: expected NAME=RUN_FOLDER")
        name, run_dir = item.split("=", 1)
        runs[name] = run_folder(run_dir, "--training-run")
    src = TestSource(files=list(args.test), synthetic=(args.synthetic, (96, 128), 9001) if args.synthetic else None,
                     max_samples=args.max_samples)
    physics = shipped_model_path() if args.model in ("learned", "default") else args.model
    res = write_evaluation(evaluate_models(
        src, physics=physics, prior_free=args.prior_free, mse_only=args.mse_only, real=list(args.real),
        s5_frequencies=tuple(args.s5), s6_frequencies=tuple(args.s6), methods=tuple(args.methods),
        filtered_window=args.window, speed=not args.no_speed, training_runs=runs, cycles=list(args.cycles)),
        args.output)
    print(res["markdown"])
    print(f"wrote {args.output}/eval.md, eval.json, {', '.join(res['figures'])}")
    return 0
