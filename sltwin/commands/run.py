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

from ..errors import CommandError
from ..outputs import claim

from ..argtypes import nonnegative_float, positive_float

HELP = "calibrate camera + projector from board captures or point observations (seed + bundle adjustment)"


def exit_codes() -> list:
    """(error type, exit code, message prefix) of the errors with their own exit code (imported
    when needed: ``calib.errors`` loads the whole calib package, which ``calib --help`` need not)."""
    from calib.errors import BundleAdjustmentError, InitError, ObservationError, OutputError

    return [(ObservationError, 3, "observations: "), (InitError, 4, "initialisation: "),
            (BundleAdjustmentError, 5, "bundle adjustment: "), (OutputError, 6, "")]


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
    p.add_argument("--loss-scale", type=positive_float, default=3.0, help="robust loss scale, in residual sigmas")
    p.add_argument("--outlier-threshold", type=nonnegative_float, default=5.0,
                   help="reject points beyond this many robust sigmas (0: keep all)")
    p.add_argument("--no-view-noise", action="store_true",
                   help="one noise level per device (default: a view whose residuals are more than twice the "
                        "median view's gets its own, and the adjustment runs again; docs/calib.md)")
    p.add_argument("--board-warp", nargs="?", choices=("auto", "on", "off"), const="on", default="auto",
                   help="estimate the board's 2-parameter warp (mrcal's calobject_warp): auto (default: where the "
                        "views allow it, 4 or more), on, off")
    p.add_argument("--uncertainty", choices=("model", "jackknife", "bootstrap"), default="model",
                   help="model (default): the per-pose error model's sigmas (the adjustment's independent-residual "
                        "ones beside them); jackknife / bootstrap: also the spread over resampled poses, with a "
                        "warning where it and the reported sigma disagree by more than 1.5x")
    p.add_argument("--draws", type=int, default=30, help="bootstrap runs (default 30)")
    p.add_argument("--no-camera-error-transfer", action="store_true",
                   help="treat projector pixels as independent of the camera's detection errors (default: "
                        "model how a camera error moves the projector pixel read there, where the "
                        "observations carry dprj_dcam)")
    p.add_argument("--skew-tol", type=positive_float, default=0.01, help="px; see calib.io.mrcal_model")
    p.add_argument("--no-skew-check", action="store_true",
                   help="skip the refit with skew free that tells whether a zero-skew model fits the data "
                        "(calib.uncertainty.skew_check; run when skew is not estimated; a needed skew is a warning)")
    p.add_argument("--figures", choices=("summary", "all", "auto", "none"), default="summary",
                   help="summary (default): residuals.png; all: also the per-pose panels (residuals_per_pose.png, "
                        "residuals_on_board.png; one panel per device and view); auto: all up to 12 views; none")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")


def parse_fix(items) -> tuple[dict, dict]:
    """``--fix`` items -> ({device: [names held at the seed]}, {device: [(name, value)]})."""
    fixed = {"camera": [], "projector": []}
    values = {"camera": [], "projector": []}
    for f in items:
        dev, _, name = f.partition(".")
        name, eq, value = name.partition("=")
        if dev not in fixed or not name:
            raise CommandError(f"--fix {f!r}: expected camera.PARAM[=VALUE] or projector.PARAM[=VALUE]")
        if not eq:
            fixed[dev].append(name)
            continue
        try:
            values[dev].append((name, float(value)))
        except ValueError:
            raise CommandError(f"--fix {f!r}: {value!r} is not a number") from None
    return fixed, values


def ba_config(args):
    """The adjustment settings the options ask for (a ``calib.adjustment.problem.BAConfig``)."""
    from calib.adjustment.problem import BAConfig, DeviceConfig
    from calib.errors import BundleAdjustmentError

    fixed, values = parse_fix(args.fix)
    n_dist = {"camera": args.camera_distortion, "projector": args.projector_distortion}
    try:
        devices = {d: DeviceConfig(args.distortion if n_dist[d] is None else n_dist[d], args.skew,
                                   tuple(fixed[d]), tuple(values[d])) for d in ("camera", "projector")}
        return BAConfig(mode=args.mode, camera=devices["camera"], projector=devices["projector"],
                        camera_error_transfer=not args.no_camera_error_transfer,
                        loss=args.loss, loss_scale=args.loss_scale,
                        outlier_threshold=args.outlier_threshold or None)
    except BundleAdjustmentError as exc:      # an option, not the adjustment, is wrong: exit 2
        raise CommandError(str(exc)) from None


def load_observations(paths):
    """``--observations``: one observation JSON, or a camera/projector Bouguet .mat pair ('-': none)."""
    from calib.errors import ObservationError
    from calib.observations import from_bouguet, read_observations_json

    try:
        if len(paths) == 1 and paths[0].lower().endswith(".json"):
            return read_observations_json(paths[0])
        if len(paths) != 2:
            raise CommandError(f"--observations takes one JSON file or two .mat files (camera projector, "
                               f"'-' for none); got {len(paths)} path(s)")
        cam, prj = (None if p == "-" else p for p in paths)
        return from_bouguet(cam, prj)
    except ObservationError as exc:           # an unreadable input file: exit 2, not 3
        raise CommandError(str(exc)) from None


def run(args) -> int:
    from calib.io.outputs import summary_table
    from calib.pipeline import calibrate_captures, calibrate_observations
    from calib.uncertainty.assess import uncertainty_table

    if (args.captures is None) == (args.observations is None):
        raise CommandError("give either a CAPTURES folder or --observations FILE(S)")
    claim(args.output, "dir", inputs=[args.captures, args.capture_toml, *(args.observations or [])])
    if args.draws < 3:
        raise CommandError(f"--draws: expected >= 3 bootstrap runs, got {args.draws}")
    config = ba_config(args)
    extra = {"board_warp": {"auto": "auto", "on": True, "off": False}[args.board_warp],
             "resample": "none" if args.uncertainty == "model" else args.uncertainty, "draws": args.draws,
             "skew_tol_px": args.skew_tol, "skew_check": not args.no_skew_check,
             "view_noise": not args.no_view_noise, "figures": args.figures}
    if args.captures is not None:
        result = calibrate_captures(args.captures, args.output, config, capture_toml=args.capture_toml,
                                    method=args.method, strict=args.strict, degree=args.phase_fit_degree, **extra)
    else:
        result = calibrate_observations(load_observations(args.observations), args.output, config, **extra)
    print(summary_table(result.calibration, result.observations,
                        result.captured.skipped if result.captured is not None else None))
    if result.calibration.uncertainty is not None:
        print()
        print(uncertainty_table(result.calibration.uncertainty))
    print()
    print("run: " + ", ".join(f"{k} {v:.2f} s" for k, v in result.stages_s.items())
          + f"; peak memory {result.peak_memory_mb:.0f} MB")
    return 0
