"""The ``calib`` command line: a thin layer over functions users can call from Python.

Each sub-command lives in its own module exposing ``add_arguments(parser)`` and
``run(args) -> int``; ``COMMANDS`` lists them. Errors of the toolkit (``CalibError`` and the other
packages' error types, all ``ValueError`` subclasses) end the command with exit code 2 and their
message, never a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import sys

#: (sub-command, module, one-line help). Modules are imported only when their command runs.
#: A CLI module must import only light modules at top level (heavy ones inside ``run``).
COMMANDS = [
    ("run", "calib.cli_run", "calibrate camera + projector from point observations (seed + bundle adjustment)"),
    ("reconstruct", "calib.cli_reconstruct", "absolute phase + calibration -> point cloud (PLY)"),
    ("twin", "twin_mapping.cli", "calibration -> digital-twin parameters (+ Blender scene script)"),
    ("report", "reports.cli", "twin-equivalence report (HTML + Markdown)"),
    ("demo", "calib.demo", "the main job on the built-in default system"),
    ("unwrap", "unwrap.cli", "absolute phase, fringe order and masks of a fringe capture (HDF5 + PNG)"),
    ("plan-fringes", "unwrap.cli_plan", "predicted fringe-order error rate vs number of images"),
    ("render", "synth.cli_render", "render a scene TOML to PNG images + HDF5 ground truth"),
    ("render-board", "synth.cli_render_board", "render the paper's calibration session from the twin"),
    ("export", "synth.cli_export", "twin training data or a real capture as sharded, resumable HDF5"),
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="calib", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, module, helptext in COMMANDS:
        p = sub.add_parser(name, help=helptext, description=helptext)
        p.set_defaults(_module=module)
        importlib.import_module(module).add_arguments(p)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    module = importlib.import_module(args._module)
    try:
        return int(module.run(args) or 0)
    except (ValueError, FileNotFoundError) as exc:  # toolkit errors subclass ValueError
        print(f"calib {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"calib {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
