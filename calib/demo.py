"""``calib demo``: the main job on the built-in default system.

Today: the paper's real system -> its digital twin (table S3 beside ours), twin.json and the Blender
scene script, written under the output folder.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", default="out/demo", help="output folder (default: %(default)s)")


def run(args) -> int:
    from twin_mapping import cli as twin_cli

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    print("== [1/1] built-in real system -> digital twin (calib twin)")
    twin_args = argparse.Namespace(calibration=[], output=str(out / "twin.json"),
                                   blender_script=str(out / "twin_scene.py"), blender=False,
                                   repair_rotation=False, camera_size=None, projector_size=None, paper="auto")
    twin_cli.run(twin_args)
    print(f"\ndemo done in {time.perf_counter() - t0:.1f} s; outputs in {out}/")
    return 0
