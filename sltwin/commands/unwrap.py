"""``calib unwrap CAPTURE_DIR [--method mf|mw|nt|gray] [--model learned|PATH] -o OUT``: absolute phase, k,
masks, previews (``--model``: by the learned network, with a confidence map)."""
from __future__ import annotations

from sltwin.errors import CommandError

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
    parser.add_argument("--min-modulation", type=float, default=None,
                        help="minimum modulation B in grey levels (default 2 %% of full scale)")
    parser.add_argument("-o", "--output", required=True, help="output folder (unwrap.h5 + PNG previews)")
    parser.add_argument("--model", default=None, metavar="learned|PATH",
                        help="unwrap with the learned network instead: 'learned' (the shipped model) or a "
                             "checkpoint; writes the same unwrap.h5 plus confidence and order_traditional")
    parser.add_argument("--outside", choices=["raise", "warn"], default="raise",
                        help="--model with frequencies far outside its training range: refuse (default) or warn")
    parser.add_argument("--no-previews", action="store_true", help="skip the PNG previews")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress messages")


def run(args) -> int:
    import numpy as np

    from unwrap.pipeline import unwrap_capture, write_results

    if args.model is not None:
        from unwrap.learned.capture import unwrap_capture_learned

        if args.method not in (None, "mf", "mw", "nt"):
            raise CommandError(f"--model works with --method mf, mw or nt, not {args.method}")
        results = unwrap_capture_learned(args.capture_dir, args.method or "mf", args.model, preset=args.preset,
                                         pose=args.pose, min_modulation=args.min_modulation,
                                         on_outside=args.outside, progress=True)
    else:
        results = unwrap_capture(args.capture_dir, args.method, preset=args.preset, pose=args.pose,
                                 min_modulation=args.min_modulation, progress=True)
    path = write_results(results, args.output, previews=not args.no_previews,
                         attrs={"capture": str(args.capture_dir)})
    for o, r in results.items():
        u = r.result
        print(f"{o}: method {u.method}, frequency {u.frequency:g}, valid {100 * np.mean(u.valid):.1f} %, "
              f"k in [{int(u.order[u.valid].min()) if u.valid.any() else -1}, "
              f"{int(u.order.max())}]")
        if "confidence" in r.extras:
            changed = (u.order != r.extras["order_traditional"]) & u.valid
            print(f"   learned: {int(changed.sum())} orders differ from the traditional ones; median confidence "
                  f"{float(np.median(r.extras['confidence'][u.valid])) if u.valid.any() else 0:.3f}")
    print(f"wrote {path}")
    return 0
