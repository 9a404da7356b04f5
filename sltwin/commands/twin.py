"""``calib twin``: calibration -> digital-twin parameters, printed beside the paper's table S3."""
from __future__ import annotations

import argparse
import json

from ..outputs import claim

from ..argtypes import positive_int

HELP = "calibration -> digital-twin parameters (+ Blender scene script)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("calibration", nargs="*", metavar="CALIBRATION",
                   help="calibration.json, an OpenCV .xml/.yml, two .cameramodel or two Bouguet .mat "
                        "files (camera, projector); none: the built-in system (the paper's real system)")
    p.add_argument("-o", "--output", default="twin.json", help="twin.json to write (default: %(default)s)")
    p.add_argument("--blender-script", metavar="SCENE.py", help="also write a Blender script that builds the twin")
    p.add_argument("--blender", action="store_true",
                   help="check the twin inside Blender (needs bpy): project points through Blender's cameras")
    p.add_argument("--repair-rotation", action="store_true",
                   help="replace a rounded rotation by the nearest rotation (SVD) instead of refusing it; reported")
    p.add_argument("--camera-size", nargs=2, type=positive_int, metavar=("W", "H"))
    p.add_argument("--projector-size", nargs=2, type=positive_int, metavar=("W", "H"))
    p.add_argument("-q", "--quiet", action="store_true", help="write the files, print only warnings and errors")
    p.add_argument("--paper", choices=["auto", "yes", "no"], default="auto",
                   help="print the paper's table S3 beside ours (auto: when the system is the paper's)")


def write_twin(system, output, blender_script=None, paper: str = "auto", quiet: bool = False) -> dict:
    """Print the twin of ``system`` (with the paper's table S3 where it applies), write
    ``twin.json`` to ``output`` and, when asked, the Blender scene script; returns the twin."""
    from twin_mapping.blender_export import write_blender_script
    from twin_mapping.table import format_twin_table, twin_with_paper
    from twin_mapping.twin import write_twin_json

    twin = twin_with_paper(system, paper)
    if not quiet:
        print(format_twin_table(twin, "paper_table_s3" in twin))
    path = write_twin_json(twin, output)
    if not quiet:
        print(f"\nwrote {path}")
    if blender_script:
        script = write_blender_script(twin, blender_script)
        if not quiet:
            print(f"wrote {script} (blender --background --python {blender_script})")
    return twin


def run(args) -> int:
    from calib.io import load_system

    claim(args.output, "file", inputs=args.calibration)
    if args.blender_script:
        claim(args.blender_script, "file", inputs=args.calibration, option="--blender-script")

    from ..inputs import calibration_paths

    system = load_system(calibration_paths(args.calibration), repair_rotation=args.repair_rotation,
                         camera_size=args.camera_size, projector_size=args.projector_size)
    twin = write_twin(system, args.output, args.blender_script, args.paper, quiet=args.quiet)
    if args.blender:
        from twin_mapping.blender_check import check_twin_in_blender
        result = check_twin_in_blender(system, twin=twin)
        for kind in ("camera", "projector"):
            r = result[kind]
            print(f"Blender check, {kind}: {r['n_points']} points, max {r['max_px']:.2e} px, "
                  f"rms {r['rms_px']:.2e} px from our pinhole model")
        print(json.dumps({k: result[k] for k in ("camera", "projector")}))
    return 0
