"""``calib unwrap CAPTURE_DIR [--method mf|mw|nt|gray] [--model learned|PATH] [--spatial graphcut [--no-gate]]
-o OUT``: absolute phase, k, masks, previews (``--model``: by the learned network, with a confidence map;
``--spatial graphcut``: orders corrected by a graph cut, :mod:`unwrap.spatial_capture`).

The modulation threshold is 2 % of full scale unless ``--min-modulation`` sets it, or
``--max-error-rate`` derives it from the reliability model for the method, its step counts and
the noise the frames show (:func:`unwrap.pipeline.unwrap_orientation`; traditional decoders
only). Each orientation's line says the threshold, the noise and the predicted error rate of the
pixels kept. A decode whose fringe-order priors are not near integers (wrong ladder or
phase-shift convention) is refused unless ``--no-prior-check`` (the learned path checks the
traditional prior of the pair it reads).

Several captures (``calib unwrap A B C -o OUT`` or a folder of capture folders): streamed in one
process with one loaded model (:mod:`unwrap.batch`), ``OUT/<capture name>/`` each, a progress bar
with captures/s and a summary; a capture that is refused is named and skipped, and the command then
ends with exit code 2 after writing the others.
"""
from __future__ import annotations

from sltwin.errors import CommandError

from ..outputs import claim

PRESETS = ("design", "slstudio", "slmaster", "kamino-phaseshift", "procam-graycode", "kamino")
"""unwrap.capture.PRESETS plus the former name ``kamino`` (kept literal: the parser is built without
importing the library)."""

from ..argtypes import positive_float

HELP = "absolute phase, fringe order and masks of a fringe capture (HDF5 + PNG)"


def add_arguments(parser):
    parser.add_argument("capture_dir", nargs="+", metavar="CAPTURE_DIR",
                        help="capture folder (DESIGN.md layout or a scanner preset); several, or a folder of "
                             "capture folders: a batch (one OUT/<name>/ each, one loaded model)")
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
    parser.add_argument("--noise-sigma", type=positive_float, default=None, metavar="GREY",
                        help="intensity noise per frame (default: estimated from the fit residuals; 3-step "
                             "captures need it for --max-error-rate)")
    parser.add_argument("--no-prior-check", action="store_true",
                        help="decode even when the fringe-order priors are not near integers (wrong ladder or "
                             "phase-shift convention)")
    parser.add_argument("-o", "--output", required=True, help="output folder (unwrap.h5 + PNG previews)")
    parser.add_argument("--model", default=None, metavar="learned|PATH",
                        help="unwrap with the learned network instead: 'learned' (the shipped model) or a "
                             "checkpoint; writes the same unwrap.h5 plus confidence and order_traditional")
    parser.add_argument("--device", choices=["cpu", "cuda", "auto"], default=None,
                        help="with --model: where the network runs (default: a .pt on the CPU, an .onnx on CUDA "
                             "where its onnxruntime offers it; auto: CUDA where present)")
    parser.add_argument("--precision", choices=["fp32", "fp16", "bf16"], default="fp32",
                        help="with a .pt --model: the forward's arithmetic (fp16 / bf16 under autocast; fp16 on "
                             "CUDA only; orders can move where two classes tie: docs/speed.md)")
    parser.add_argument("--outside", choices=["raise", "warn"], default="raise",
                        help="--model with frequencies far outside its training range: refuse (default) or warn")
    parser.add_argument("--spatial", choices=["graphcut"], default=None,
                        help="correct the fringe orders by a graph cut over the whole image (data term: the "
                             "prior's likelihood, or the network's with --model; smoothness: wrap-consistent "
                             "high phase, cut at depth edges; docs/unwrap.md)")
    parser.add_argument("--no-gate", action="store_true",
                        help="with --spatial: keep every correction (default: only where the traditional order "
                             "is unreliable and, with --model, the network is sure)")
    parser.add_argument("--global-bound", action="store_true",
                        help="with --spatial graphcut (MF, no --model): widen the prior's likelihood by the bound on "
                             "the coarse phase's bias from global light (unwrap.global_light; helps bias-dominated "
                             "scenes, costs some accuracy on clean ones: docs/learned.md)")
    parser.add_argument("--no-previews", action="store_true", help="skip the PNG previews")
    parser.add_argument("--check-frames", action="store_true",
                        help="also measure how much the frames' brightness fluctuates from frame to frame (sets "
                             "of >= 4 steps; unwrap.frame_jitter) and note it when above 1 %% of the background; "
                             "reads the top set's frames again (0.5-2 s): off by default")
    parser.add_argument("--low-memory", action="store_true",
                        help="return freed memory to the system at once (glibc): a lower peak (900x700 with --model: "
                             "~375 -> ~305 MB) for 10-30 %% more CPU time (docs/speed.md)")
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


def decoder(args):
    """``decode(folder) -> {orientation: OrientationResult}`` with the options of the command; the
    model (if any) is loaded once, before any capture, so a bad model fails at once."""
    if args.no_gate and args.spatial is None:
        raise CommandError("--no-gate belongs to --spatial graphcut")
    if args.global_bound and (args.spatial is None or args.model is not None or args.method not in (None, "mf")):
        raise CommandError("--global-bound belongs to --spatial graphcut with the prior's data term: MF, no --model")
    model = None
    if args.model is None and (args.device is not None or args.precision != "fp32"):
        raise CommandError("--device / --precision belong to --model")
    if args.model is not None:
        from unwrap.learned.runtime import load_predictor
        from unwrap.methods import PAIR_METHODS

        from ..inputs import KIND_NAMES

        if args.method not in (None, *PAIR_METHODS):
            raise CommandError(f"--model works with --method mf, mw or nt, not {args.method}")
        if args.spatial is None and (args.max_error_rate is not None or args.noise_sigma is not None):
            raise CommandError("--max-error-rate / --noise-sigma set the threshold from the traditional decoders' "
                               "reliability model; with --model give --min-modulation instead")
        model = load_predictor(args.model, device=args.device, precision=args.precision)
        kind = model.arch.get("kind")
        if kind != "physics":           # the prior-free baseline has no traditional prior to correct
            raise CommandError(f"--model {args.model}: a {KIND_NAMES.get(kind, kind)} model; --model takes a "
                               "physics-aware one")
    if args.spatial is not None:
        from unwrap.methods import PAIR_METHODS
        from unwrap.spatial_capture import unwrap_capture_spatial

        if args.method not in (None, *PAIR_METHODS):
            raise CommandError(f"--spatial works with --method mf, mw or nt, not {args.method}")
        if args.max_error_rate is not None:
            raise CommandError("--max-error-rate sets the traditional decoders' threshold; with --spatial give "
                               "--min-modulation")
        return lambda folder, progress=True: unwrap_capture_spatial(
            folder, args.method or "mf", model=model, use_gate=not args.no_gate, preset=args.preset,
            pose=args.pose, min_modulation=args.min_modulation, noise_sigma=args.noise_sigma,
            check_prior=not args.no_prior_check, on_outside=args.outside, progress=progress,
            global_bound=args.global_bound)
    if model is not None:
        from unwrap.learned.capture import unwrap_capture_learned

        return lambda folder, progress=True: unwrap_capture_learned(
            folder, args.method or "mf", model, preset=args.preset, pose=args.pose,
            min_modulation=args.min_modulation, on_outside=args.outside, check_prior=not args.no_prior_check,
            progress=progress)
    from unwrap.pipeline import unwrap_capture

    return lambda folder, progress=True: unwrap_capture(
        folder, args.method, preset=args.preset, pose=args.pose, min_modulation=args.min_modulation,
        max_error_rate=args.max_error_rate, noise_sigma=args.noise_sigma, check_prior=not args.no_prior_check,
        progress=progress)


def report(results, path) -> None:
    """The per-orientation lines of one capture."""
    import numpy as np

    for o, r in results.items():
        print(describe(o, r))
        if "confidence" in r.extras or "p_wrong_traditional" in r.extras:
            u = r.result
            changed = (u.order != r.extras["order_traditional"]) & u.valid
            print(f"   {u.method}: {int(changed.sum())} orders differ from the traditional ones; median confidence "
                  f"{float(np.median(r.extras['confidence'][u.valid])) if u.valid.any() else 0:.3f}"
                  if "confidence" in r.extras else f"   {u.method}: {int(changed.sum())} orders differ from the "
                  "traditional ones")
    print(f"wrote {path}")


def run_batch(args, folders, decode) -> int:
    """Several captures: streamed, one output sub-folder each, a summary (module docstring)."""
    import time
    from pathlib import Path

    from unwrap.batch import output_names, stream, summary
    from unwrap.pipeline import write_results

    if args.model is not None:      # many captures: numba's plane-fit kernel pays for its ~1 s load
        from unwrap import warmup     # unless the features' plane fits run in C (no C compiler here)
        from unwrap.learned.fast_features import native_plane_filter

        if not native_plane_filter():
            warmup.plane_filter()
    out = Path(args.output)
    names = dict(zip(folders, output_names(folders)))
    t0, items = time.perf_counter(), []

    def decode_and_write(folder):
        res = decode(folder, progress=False)
        return res, write_results(res, out / names[folder], previews=not args.no_previews,
                                  attrs={"capture": str(folder)}, previews_beside=args.model is None)
    for item in stream(folders, decode_and_write, progress=not args.quiet,
                       label="unwrap" + (" (learned)" if args.model else "")):
        items.append(item)
        if item.error is None and not args.quiet:
            valid = ", ".join(f"{o} valid {100 * r.result.valid.mean():.1f} %" for o, r in item.result[0].items())
            print(f"{item.folder}: {valid}; wrote {item.result[1]} ({item.seconds:.2f} s)")
        item.result = None              # streamed: a capture's maps are not kept once written
    print(summary(items, time.perf_counter() - t0))
    failed = [i for i in items if i.error is not None]
    if failed:
        raise CommandError(f"{len(failed)} of {len(items)} captures refused (the others were written): "
                           + "; ".join(f"{i.folder}: {i.error}" for i in failed[:5]))
    return 0


def run(args) -> int:
    from pathlib import Path

    from unwrap.batch import capture_folders, is_capture
    from unwrap.errors import UnwrapError
    from unwrap.pipeline import write_results

    claim(args.output, "dir", inputs=[*args.capture_dir, args.model])
    if args.low_memory:
        import sys

        from unwrap.memory import fix_mmap_threshold

        if not fix_mmap_threshold() and not args.quiet:
            print("calib unwrap: --low-memory has no effect here (it needs glibc's malloc)", file=sys.stderr)
    decode = decoder(args)
    one = Path(args.capture_dir[0])
    if len(args.capture_dir) > 1 or (one.is_dir() and not is_capture(one)
                                     and any(q.is_dir() and is_capture(q) for q in one.iterdir())):
        try:
            folders = capture_folders(args.capture_dir)
        except UnwrapError as exc:
            raise CommandError(str(exc)) from None
        if args.check_frames:        # not silently skipped: the batch has no per-capture diagnosis
            raise CommandError("--check-frames checks one capture; give it one capture folder at a time")
        return run_batch(args, folders, decode)
    results = decode(one)
    # previews drawn beside the write, except with --model: there their temporaries beside the write's
    # raised the peak by up to ~30 MB (docs/speed.md, session 10)
    path = write_results(results, args.output, previews=not args.no_previews,
                         attrs={"capture": str(args.capture_dir[0])}, previews_beside=args.model is None)
    report(results, path)
    if args.check_frames:
        from unwrap.frame_jitter import frame_check   # per-frame fluctuation (docs/unwrap.md)

        print(f"note: {frame_check(one, args.preset, args.pose)}")
    return 0
