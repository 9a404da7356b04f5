"""``calib render-board [SYSTEM...] -o captures/``: the paper's calibration session rendered from
the twin (9 board poses, v/h fringes, 12 steps, frequencies 1 8 48, white), with truth.json;
``--pattern graycode`` renders a Gray-code session instead (column/row bits with inverses, white,
black: the layout of unwrap.graycode_capture)."""
from __future__ import annotations

from ..errors import CommandError
from ..outputs import output_dir

HELP = "render the paper's calibration session from the twin"


def add_arguments(parser):
    parser.add_argument("system", nargs="*", help="calibration file(s) of the system (default: built-in)")
    parser.add_argument("-o", "--output", required=True, help="capture folder to write")
    parser.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    parser.add_argument("--steps", type=int, default=12, help="phase steps per frequency (default 12)")
    parser.add_argument("--frequencies", type=float, nargs="+", default=[1, 8, 48],
                        help="fringe periods across the pattern (default 1 8 48)")
    parser.add_argument("--poses", type=int, default=9, help="number of board poses (default 9)")
    parser.add_argument("--bits", type=int, default=8, choices=(8, 10, 12, 16), help="image bit depth")
    parser.add_argument("--no-noise", action="store_true", help="noise-free images")
    parser.add_argument("--truth-h5", action="store_true", help="also write pose_XX/truth.h5")
    parser.add_argument("--pattern", choices=("phase-shift", "graycode"), default="phase-shift",
                        help="phase-shift fringes (default) or Gray code only (OpenCV's GrayCodePattern layout)")
    parser.add_argument("--gray-block", type=int, default=1,
                        help="Gray code: projector pixels per code step (default 1)")


def run(args) -> int:
    from calib.io import load_system
    from synth.scenes.board_session import render_board_session
    from synth.effects.spec import Noise

    output_dir(args.output)
    if args.gray_block < 1:
        raise CommandError(f"--gray-block: expected >= 1 projector px, got {args.gray_block}")
    if args.steps < 3:
        raise CommandError(f"--steps: expected >= 3, got {args.steps}")
    system = load_system(args.system)
    truth = render_board_session(args.output, system, steps=args.steps, frequencies=args.frequencies,
                                 n_poses=args.poses, bits=args.bits, seed=args.seed,
                                 noise=None if args.no_noise else Noise(seed=args.seed),
                                 truth_h5=args.truth_h5, pattern=args.pattern, gray_block_px=args.gray_block)
    print(f"wrote {len(truth['board_poses'])} poses to {args.output} (capture.toml, truth.json), "
          f"{sum(truth['render_seconds']):.1f} s")
    return 0
