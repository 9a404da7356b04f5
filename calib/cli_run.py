"""``calib run``: calibrate camera + projector from board captures or point observations
(Zhang seeds + bundle adjustment).

    calib run CAPTURES -o OUT                      # images: unwrap, detect, phase fit, adjust
    calib run CAPTURES --capture-toml my.toml -o OUT   # a real scanner's folder, described aside
    calib run --observations CamCalibResult.mat PrjCalibResult.mat -o OUT
    calib run --observations observations.json -o OUT

Exit codes: 0 success; 2 invalid input or option (file unreadable, bad schema); 3 observations
insufficient (too few views or points); 4 initialisation failed (degenerate views, e.g. all
fronto-parallel); 5 adjustment failed (singular, too many outliers); 6 outputs could not be
written.
"""
from __future__ import annotations

import sys

EXIT_OK, EXIT_INPUT, EXIT_OBSERVATIONS, EXIT_INIT, EXIT_ADJUST, EXIT_OUTPUT = 0, 2, 3, 4, 5, 6


def add_arguments(p):
    p.add_argument("captures", nargs="?", metavar="CAPTURES",
                   help="capture folder (DESIGN.md layout: capture.toml + pose_XX/ frames)")
    p.add_argument("--observations", nargs="+", metavar="FILE",
                   help="instead of CAPTURES: camera and projector Bouguet .mat results (either may be '-' "
                        "to leave it out), or one observation JSON (schema: docs/calib.md)")
    p.add_argument("--capture-toml", metavar="TOML",
                   help="capture description kept outside CAPTURES (real scanners' folders; "
                        "see calib/data/captures/)")
    p.add_argument("--method", choices=("mf", "mw", "nt", "gray"),
                   help="temporal unwrapping method (default: capture.toml's or the preset's)")
    p.add_argument("--strict", action="store_true",
                   help="refuse the whole run when a pose cannot be used (default: skip it and report)")
    p.add_argument("--phase-fit-degree", type=int, choices=(1, 2), default=2,
                   help="local polynomial degree of the projector-coordinate fit around each feature")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--mode", choices=("joint", "single"), default="joint",
                   help="joint: one board pose per view shared by both devices (default); "
                        "single: each device calibrated alone")
    p.add_argument("--distortion", type=int, choices=(0, 4, 5, 8, 12), default=5,
                   help="distortion terms of both devices (default 5)")
    p.add_argument("--camera-distortion", type=int, choices=(0, 4, 5, 8, 12))
    p.add_argument("--projector-distortion", type=int, choices=(0, 4, 5, 8, 12))
    p.add_argument("--skew", action="store_true",
                   help="estimate skew (then mrcal .cameramodel files can be written only if it is tiny)")
    p.add_argument("--fix", action="append", default=[], metavar="DEVICE.PARAM[=VALUE]",
                   help="hold a parameter at its seed, e.g. camera.k3 or projector.intrinsics, or at a given "
                        "value, e.g. camera.cx=843.5 (repeatable)")
    p.add_argument("--loss", choices=("linear", "huber", "cauchy"), default="linear")
    p.add_argument("--loss-scale", type=float, default=3.0, help="robust loss scale, in residual sigmas")
    p.add_argument("--outlier-threshold", type=float, default=5.0,
                   help="reject points beyond this many robust sigmas (0: keep all)")
    p.add_argument("--board-warp", action="store_true", help="estimate a 2-parameter board warp (mrcal's)")
    p.add_argument("--no-camera-error-transfer", action="store_true",
                   help="treat projector pixels as independent of the camera's detection errors (default: "
                        "model how a camera error moves the projector pixel read there, where the "
                        "observations carry dprj_dcam)")
    p.add_argument("--skew-tol", type=float, default=0.01, help="px; see calib.io.mrcal_model")
    p.add_argument("--no-skew-check", action="store_true",
                   help="skip the refit with skew free that tells whether a zero-skew model fits the data "
                        "(calib.skew_check; run when skew is not estimated)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")


def _load(paths):
    from .observations import from_bouguet, read_observations_json

    if len(paths) == 1 and paths[0].lower().endswith(".json"):
        return read_observations_json(paths[0])
    if len(paths) != 2:
        from .observations import ObservationError
        raise ObservationError(f"--observations takes one JSON file or two .mat files (camera projector, "
                               f"'-' for none); got {len(paths)} path(s)")
    cam, prj = (None if p == "-" else p for p in paths)
    return from_bouguet(cam, prj)


def _skew_check(obs, cal, config, progress) -> dict:
    """Refit with skew free (calib.skew_check); a significant skew is printed even with -q.
    Returns {"skew_check": ...} for calibration.json, or {} when nothing was checked."""
    from .skew_check import check_skew

    progress("skew check: refitting with skew free")
    try:
        check = check_skew(obs, cal, config)
    except ValueError as exc:       # the refit's adjustment errors
        progress(f"skew check: the refit failed ({exc}); not checked")
        return {}
    if check is None:
        return {}
    if check.significant():
        print(f"calib run: warning: {check.message()}", file=sys.stderr, flush=True)
    else:
        progress(check.message())
    return {"skew_check": check.to_dict()}


def run(args) -> int:
    from .bundle_adjustment import BAConfig, BundleAdjustmentError, DeviceConfig
    from .calibrate import run_calibration
    from .calibration_report import summary_table, write_outputs
    from .errors import FormatError
    from .observations import ObservationError
    from .zhang import InitError

    def progress(msg):
        if not args.quiet:
            print(msg, file=sys.stderr, flush=True)

    if (args.captures is None) == (args.observations is None):
        print("calib run: error: give either a CAPTURES folder or --observations FILE(S)", file=sys.stderr)
        return EXIT_INPUT
    captured = None
    if args.captures is not None:
        from .captures import CaptureError, observations_from_captures
        from unwrap.errors import UnwrapError
        try:
            captured = observations_from_captures(args.captures, capture_toml=args.capture_toml,
                                                  method=args.method, strict=args.strict,
                                                  degree=args.phase_fit_degree, keep_images=True,
                                                  progress=progress)
        except ObservationError as exc:
            print(f"calib run: error: observations: {exc}", file=sys.stderr)
            return EXIT_OBSERVATIONS
        except (CaptureError, UnwrapError, FormatError, FileNotFoundError, ValueError) as exc:
            print(f"calib run: error: {exc}", file=sys.stderr)
            return EXIT_INPUT
        obs = captured.observations
    else:
        try:
            obs = _load(args.observations)
        except (ObservationError, FormatError) as exc:
            print(f"calib run: error: {exc}", file=sys.stderr)
            return EXIT_INPUT
    fixed = {"camera": [], "projector": []}
    values = {"camera": [], "projector": []}
    for f in args.fix:
        dev, _, name = f.partition(".")
        name, eq, value = name.partition("=")
        if dev not in fixed or not name:
            print(f"calib run: error: --fix {f!r}: expected camera.PARAM[=VALUE] or projector.PARAM[=VALUE]",
                  file=sys.stderr)
            return EXIT_INPUT
        if eq:
            try:
                values[dev].append((name, float(value)))
            except ValueError:
                print(f"calib run: error: --fix {f!r}: {value!r} is not a number", file=sys.stderr)
                return EXIT_INPUT
        else:
            fixed[dev].append(name)
    devices = obs.devices()
    mode = args.mode
    if mode == "joint" and len(devices) < 2:
        progress(f"only {devices} observed: calibrating in single-device mode")
        mode = "single"
    try:
        config = BAConfig(
            mode=mode,
            camera=DeviceConfig(args.camera_distortion if args.camera_distortion is not None else args.distortion,
                                args.skew, tuple(fixed["camera"]), tuple(values["camera"])),
            projector=DeviceConfig(args.projector_distortion if args.projector_distortion is not None
                                   else args.distortion, args.skew, tuple(fixed["projector"]),
                                   tuple(values["projector"])),
            board_warp=args.board_warp, camera_error_transfer=not args.no_camera_error_transfer, loss=args.loss, loss_scale=args.loss_scale,
            outlier_threshold=args.outlier_threshold or None, progress=progress)
    except BundleAdjustmentError as exc:
        print(f"calib run: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    progress(f"{len(obs.views)} view(s) from {obs.source}; devices {devices}; mode {mode}")
    try:
        cal = run_calibration(obs, config)
    except ObservationError as exc:
        print(f"calib run: error: observations: {exc}", file=sys.stderr)
        return EXIT_OBSERVATIONS
    except InitError as exc:
        print(f"calib run: error: initialisation: {exc}", file=sys.stderr)
        return EXIT_INIT
    except BundleAdjustmentError as exc:
        print(f"calib run: error: bundle adjustment: {exc}", file=sys.stderr)
        return EXIT_ADJUST
    extra = {} if captured is None else {"captures": captured.summary()}
    if not args.skew and not args.no_skew_check:
        extra.update(_skew_check(obs, cal, config, progress))
    try:
        written = write_outputs(cal, obs, args.output, skew_tol_px=args.skew_tol, extra=extra or None)
        if captured is not None:
            from .capture_outputs import write_capture_outputs
            written.update(write_capture_outputs(captured, args.output))
    except OSError as exc:
        print(f"calib run: error: cannot write outputs to {args.output}: {exc}", file=sys.stderr)
        return EXIT_OUTPUT
    print(summary_table(cal))
    for name, path in written.items():
        progress(f"wrote {name}: {path}")
    return EXIT_OK
