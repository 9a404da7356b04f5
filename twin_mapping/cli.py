"""``calib twin``: calibration -> digital-twin parameters, printed beside the paper's table S3."""
from __future__ import annotations

import argparse
import json


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
    p.add_argument("--camera-size", nargs=2, type=int, metavar=("W", "H"))
    p.add_argument("--projector-size", nargs=2, type=int, metavar=("W", "H"))
    p.add_argument("--paper", choices=["auto", "yes", "no"], default="auto",
                   help="print the paper's table S3 beside ours (auto: when the system is the paper's)")


def run(args) -> int:
    from calib.io import load_system

    from .blender_export import write_blender_script
    from .table import format_twin_table, is_papers_system
    from .twin import to_twin, write_twin_json

    system = load_system(args.calibration, repair_rotation=args.repair_rotation,
                         camera_size=args.camera_size, projector_size=args.projector_size)
    twin = to_twin(system)
    with_paper = args.paper == "yes" or (args.paper == "auto" and is_papers_system(system))
    if with_paper:
        from .paper import compare_with_table_s3
        twin["paper_table_s3"] = compare_with_table_s3(twin)
    print(format_twin_table(twin, with_paper))
    path = write_twin_json(twin, args.output)
    print(f"\nwrote {path}")
    if args.blender_script:
        print(f"wrote {write_blender_script(twin, args.blender_script)} "
              f"(blender --background --python {args.blender_script})")
    if args.blender:
        from .blender_check import check_twin_in_blender
        result = check_twin_in_blender(system, twin=twin)
        for kind in ("camera", "projector"):
            r = result[kind]
            print(f"Blender check, {kind}: {r['n_points']} points, max {r['max_px']:.2e} px, "
                  f"rms {r['rms_px']:.2e} px from our pinhole model")
        print(json.dumps({k: result[k] for k in ("camera", "projector")}))
    return 0
