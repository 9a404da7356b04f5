"""``calib unwrap CAPTURE_DIR [--method mf|mw|nt|gray] -o OUT``: absolute phase, k, masks, previews."""
from __future__ import annotations

HELP = "absolute phase, fringe order and masks of a fringe capture (HDF5 + PNG)"


def add_arguments(parser):
    parser.add_argument("capture_dir", help="capture folder (DESIGN.md layout or a scanner preset)")
    parser.add_argument("--method", choices=["mf", "mw", "nt", "gray"], default=None,
                        help="temporal unwrapping method (default: the capture's: mf for the "
                             "DESIGN layout and slstudio, gray for slmaster and kamino)")
    parser.add_argument("--preset", choices=["design", "slstudio", "slmaster", "kamino"], default=None,
                        help="capture layout (default: capture.toml [capture] preset, else recognised)")
    parser.add_argument("--pose", default=None, help="pose folder (DESIGN layout; default the first)")
    parser.add_argument("--min-modulation", type=float, default=None,
                        help="minimum modulation B in grey levels (default 2 %% of full scale)")
    parser.add_argument("-o", "--output", required=True, help="output folder (unwrap.h5 + PNG previews)")
    parser.add_argument("--no-previews", action="store_true", help="skip the PNG previews")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress messages")


def run(args) -> int:
    import numpy as np

    from unwrap.pipeline import unwrap_capture, write_results

    results = unwrap_capture(args.capture_dir, args.method, preset=args.preset, pose=args.pose,
                             min_modulation=args.min_modulation, progress=True)
    path = write_results(results, args.output, previews=not args.no_previews,
                         attrs={"capture": str(args.capture_dir)})
    for o, r in results.items():
        u = r.result
        print(f"{o}: method {u.method}, frequency {u.frequency:g}, valid {100 * np.mean(u.valid):.1f} %, "
              f"k in [{int(u.order[u.valid].min()) if u.valid.any() else -1}, "
              f"{int(u.order.max())}]")
    print(f"wrote {path}")
    return 0
