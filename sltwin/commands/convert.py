"""``calib convert INPUT... -o OUTPUT...``: a calibration from one file format into another.

    calib convert calibration.json -o rig.yml                    # OpenCV YAML (SLStudio keys)
    calib convert CamCalibResult.mat PrjCalibResult.mat -o calibration.json
    calib convert rig.xml -o camera.cameramodel projector.cameramodel

Inputs: whatever ``calib.load_system`` reads (calibration.json, OpenCV .xml/.yml, two
.cameramodel or two Bouguet .mat files); outputs by their names (``calib.save_system``): one
.json, one OpenCV .yml/.yaml/.xml (world = the camera frame), or two .cameramodel files.
"""
from __future__ import annotations

from ..outputs import claim

from ..argtypes import positive_float, positive_int

HELP = "a calibration from one file format into another (calibration.json, OpenCV YAML/XML, mrcal)"


def add_arguments(p):
    p.add_argument("inputs", nargs="+", metavar="INPUT", help="calibration file(s) (calib.load_system)")
    p.add_argument("-o", "--output", nargs="+", required=True, metavar="OUTPUT",
                   help="one .json, one .yml/.yaml/.xml, or two .cameramodel files (camera projector)")
    p.add_argument("--repair-rotation", action="store_true",
                   help="replace a rounded rotation by the nearest rotation instead of refusing it")
    p.add_argument("--skew-tol", type=positive_float, default=None, metavar="PX",
                   help="largest corner shift (px) from dropping skew that a .cameramodel may accept (default 0.01)")
    p.add_argument("--camera-size", nargs=2, type=positive_int, metavar=("W", "H"))
    p.add_argument("--projector-size", nargs=2, type=positive_int, metavar=("W", "H"))
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")


def run(args) -> int:
    from calib.io import load_system, save_system

    for path in args.output:
        claim(path, "file", inputs=args.inputs)
    from ..inputs import calibration_paths

    system = load_system(calibration_paths(args.inputs), repair_rotation=args.repair_rotation,
                         camera_size=args.camera_size, projector_size=args.projector_size)
    for path in save_system(system, args.output, skew_tol_px=args.skew_tol):
        if not args.quiet:
            print(f"wrote {path}")
    return 0
