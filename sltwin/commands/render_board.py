"""``calib render-board [SYSTEM...] -o captures/``: the paper's calibration session rendered from
the twin (9 board poses, v/h fringes, 12 steps, frequencies 1 8 48, white), with truth.json;
``--pattern graycode`` renders a Gray-code session instead (column/row bits with inverses, white,
black: the layout of unwrap.graycode_capture)."""
from __future__ import annotations

from ..errors import CommandError
from ..outputs import claim, fresh_dir

from ..argtypes import positive_float, positive_int

HELP = "render the paper's calibration session from the twin"


def add_arguments(parser):
    parser.add_argument("system", nargs="*", help="calibration file(s) of the system (default: built-in)")
    parser.add_argument("-o", "--output", required=True, help="capture folder to write")
    parser.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    parser.add_argument("--steps", type=positive_int, default=12, help="phase steps per frequency (default 12)")
    parser.add_argument("--frequencies", type=positive_float, nargs="+", default=[1, 8, 48],
                        help="fringe periods across the pattern (default 1 8 48)")
    parser.add_argument("--poses", type=positive_int, default=9, help="number of board poses (default 9)")
    parser.add_argument("--bits", type=int, default=8, choices=(8, 10, 12, 16), help="image bit depth")
    parser.add_argument("--no-noise", action="store_true", help="noise-free images")
    parser.add_argument("--truth-h5", action="store_true", help="also write pose_XX/truth.h5")
    parser.add_argument("--pattern", choices=("phase-shift", "graycode"), default="phase-shift",
                        help="phase-shift fringes (default) or Gray code only (OpenCV's GrayCodePattern layout)")
    parser.add_argument("--gray-block", type=positive_int, default=1,
                        help="Gray code: projector pixels per code step (default 1)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace a session (or render) already in OUT wholly, every pose of it; without it a "
                             "folder that holds one is refused")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress lines, only errors and warnings")


def run(args) -> int:
    from calib.io import load_system
    from synth.effects.spec import Noise
    from synth.renderer.render import check_render_memory
    from synth.scenes.board_session import render_board_session, session_patterns

    from ..inputs import calibration_paths

    claim(args.output, "dir", inputs=args.system)
    if args.gray_block < 1:
        raise CommandError(f"--gray-block: expected >= 1 projector px, got {args.gray_block}")
    if args.steps < 3:
        raise CommandError(f"--steps: expected >= 3, got {args.steps}")
    system = load_system(calibration_paths(args.system))
    # the patterns and the memory they need are checked before any file is written
    specs, _ = session_patterns(system, args.pattern, args.steps, args.frequencies, args.gray_block)
    check_render_memory(len(specs), system.camera.size)
    fresh_dir(args.output, "a rendered session", args.overwrite)
    truth = render_board_session(args.output, system, steps=args.steps, frequencies=args.frequencies,
                                 n_poses=args.poses, bits=args.bits, seed=args.seed,
                                 noise=None if args.no_noise else Noise(seed=args.seed),
                                 truth_h5=args.truth_h5, pattern=args.pattern, gray_block_px=args.gray_block)
    if not args.quiet:
        print(f"wrote {len(truth['board_poses'])} poses to {args.output} (capture.toml, truth.json), "
              f"{sum(truth['render_seconds']):.1f} s")
    return 0
