"""``calib unwrap CAPTURE_DIR [--method mf|mw|nt|gray] [--model learned|PATH] -o OUT``: absolute phase,
k, masks, previews (``--model``: by the learned network, with a confidence map).

The modulation threshold is 2 % of full scale unless ``--min-modulation`` sets it, or
``--max-error-rate`` derives it from the reliability model for the method, its step counts and
the noise the frames show (:func:`unwrap.pipeline.unwrap_orientation`; traditional decoders
only). Each orientation's line says the threshold, the noise and the predicted error rate of the
pixels kept. A decode whose fringe-order priors are not near integers (wrong ladder or
phase-shift convention) is refused unless ``--no-prior-check`` (the learned path checks the
traditional prior of the pair it reads).
"""
from __future__ import annotations

from sltwin.errors import CommandError

from ..outputs import output_dir

PRESETS = ("design", "slstudio", "slmaster", "kamino-phaseshift", "procam-graycode", "kamino")
"""unwrap.capture.PRESETS plus the former name ``kamino`` (kept literal: the parser is built without
importing the library)."""

HELP = "absolute phase, fringe order and masks of a fringe capture (HDF5 + PNG)"


def add_arguments(parser):
    parser.add_argument("capture_dir", help="capture folder (DESIGN.md layout or a scanner preset)")
    parser.add_argument("--method", choices=["mf", "mw", "nt", "gray"], default=None,
                        help="temporal unwrapping method (default: the capture's: mf for the "
                             "DESIGN layout and slstudio, gray for slmaster, kamino-phaseshift and Gray-code-only "
                             "captures)")
    parser.add_argument("--preset", choices=PRESETS, default=None,
                        help="capture layout (default: capture.toml [capture] preset, else recognised); "
                             "'kamino' is the former name of kamino-phaseshift")
    parser.add_argument("--pose", default=None, help="pose folder (DESIGN layout; default the first)")
    threshold = parser.add_mutually_exclusive_group()
    threshold.add_argument("--min-modulation", type=float, default=None,
                           help="minimum modulation B in grey levels (default 2 %% of full scale)")
    threshold.add_argument("--max-error-rate", type=float, default=None, metavar="RATE",
                           help="instead: the modulation threshold at which the method's predicted fringe-order "
                                "error rate is RATE (reliability model, this capture's steps and noise)")
    parser.add_argument("--noise-sigma", type=float, default=None, metavar="GREY",
                        help="intensity noise per frame (default: estimated from the fit residuals; 3-step "
                             "captures need it for --max-error-rate)")
    parser.add_argument("--no-prior-check", action="store_true",
                        help="decode even when the fringe-order priors are not near integers (wrong ladder or "
                             "phase-shift convention)")
    parser.add_argument("-o", "--output", required=True, help="output folder (unwrap.h5 + PNG previews)")
    parser.add_argument("--model", default=None, metavar="learned|PATH",
                        help="unwrap with the learned network instead: 'learned' (the shipped model) or a "
                             "checkpoint; writes the same unwrap.h5 plus confidence and order_traditional")
    parser.add_argument("--outside", choices=["raise", "warn"], default="raise",
                        help="--model with frequencies far outside its training range: refuse (default) or warn")
    parser.add_argument("--no-previews", action="store_true", help="skip the PNG previews")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress messages")


def describe(o: str, r) -> str:
    """One line per orientation: method, frequency, valid fraction, k range, threshold, the Gray
    block size of a Gray-code-only capture, noise, predicted error rate of the kept pixels."""
    import numpy as np

    u = r.result
    line = (f"{o}: method {u.method}, frequency {u.frequency:g}, valid {100 * np.mean(u.valid):.1f} %, "
            f"k in [{int(u.order[u.valid].min()) if u.valid.any() else -1}, {int(u.order.max())}], "
            f"modulation >= {r.min_modulation:.3g}")
    if r.quantisation_px is not None:
        line += f", Gray block centres (quantised to {r.quantisation_px:g} px)"
    if r.noise_sigma is not None:
        line += f", noise {r.noise_sigma:.3g}"
    if r.predicted_error_rate is not None:
        n = r.predicted_error_rate * int(np.sum(u.valid))
        line += f", predicted wrong orders <= {r.predicted_error_rate:.2g} (~{n:.3g} pixels)"
    return line


def run(args) -> int:
    import numpy as np

    from unwrap.pipeline import unwrap_capture, write_results

    output_dir(args.output)
    if args.model is not None:
        from unwrap.learned.capture import unwrap_capture_learned
        from unwrap.methods import PAIR_METHODS

        if args.method not in (None, *PAIR_METHODS):
            raise CommandError(f"--model works with --method mf, mw or nt, not {args.method}")
        if args.max_error_rate is not None or args.noise_sigma is not None:
            raise CommandError("--max-error-rate / --noise-sigma set the threshold from the traditional decoders' "
                               "reliability model; with --model give --min-modulation instead")
        results = unwrap_capture_learned(args.capture_dir, args.method or "mf", args.model, preset=args.preset,
                                         pose=args.pose, min_modulation=args.min_modulation,
                                         on_outside=args.outside, check_prior=not args.no_prior_check,
                                         progress=True)
    else:
        results = unwrap_capture(args.capture_dir, args.method, preset=args.preset, pose=args.pose,
                                 min_modulation=args.min_modulation, max_error_rate=args.max_error_rate,
                                 noise_sigma=args.noise_sigma, check_prior=not args.no_prior_check, progress=True)
    path = write_results(results, args.output, previews=not args.no_previews,
                         attrs={"capture": str(args.capture_dir)})
    for o, r in results.items():
        print(describe(o, r))
        if "confidence" in r.extras:
            u = r.result
            changed = (u.order != r.extras["order_traditional"]) & u.valid
            print(f"   learned: {int(changed.sum())} orders differ from the traditional ones; median confidence "
                  f"{float(np.median(r.extras['confidence'][u.valid])) if u.valid.any() else 0:.3f}")
    print(f"wrote {path}")
    return 0
