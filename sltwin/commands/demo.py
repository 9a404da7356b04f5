"""``calib demo``: the main job on the built-in default system, from images to the report
(:func:`sltwin.demo.run_demo`)."""
from __future__ import annotations

import argparse

from ..outputs import claim

HELP = "the main job on the built-in default system"
LOG_FORMAT = "   %(message)s"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", default="out/demo", help="output folder (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="noise seed of the simulated session")
    p.add_argument("--data", default=None, help="folder of the paper's dp-tpu data (default: ../shared/data/dp-tpu "
                                                 "beside the repository, when present)")


def run(args) -> int:
    from ..demo import run_demo

    claim(args.output, "dir", inputs=[args.data])
    run_demo(args.output, seed=args.seed, data=args.data)
    return 0
