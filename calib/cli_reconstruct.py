"""``calib reconstruct``: absolute phase + calibration -> point cloud (PLY).

    calib reconstruct --phase standardball_phase_real.mat --frequency 96 --calibration calibration.json -o ball.ply
    calib reconstruct --phase phase.h5 --frequency 48 --calibration CAM.mat PRJ.mat --method linear -o out.ply

``--phase``: a MATLAB .mat (the first 2-D array, or ``--variable``) or an HDF5 phase file of
DESIGN.md (group ``v`` dataset ``phase``). Pixels with phase 0 or NaN are invalid.
``--method``: ``distortion`` (default; distortion-aware, iterated) or ``linear`` (K[R|t], no
distortion, as the paper). ``--sphere`` also fits a sphere and prints its RMS (um).
Exit codes: 0 success; 2 invalid input.
"""
from __future__ import annotations

import sys


def add_arguments(p):
    p.add_argument("--phase", required=True, help="absolute phase (.mat or DESIGN.md HDF5)")
    p.add_argument("--variable", help="variable name in a .mat file (default: the first 2-D array)")
    p.add_argument("--frequency", type=float, required=True, help="periods across the projector pattern")
    p.add_argument("--orientation", choices=("v", "h"), default="v",
                   help="v: fringes along projector columns (u_p), h: rows (v_p)")
    p.add_argument("--calibration", nargs="+", required=True, help="calibration file(s) (calib.load_system)")
    p.add_argument("--method", choices=("distortion", "linear"), default="distortion")
    p.add_argument("--sphere", action="store_true", help="fit a sphere and print its RMS")
    p.add_argument("-o", "--output", required=True, help="PLY path")


def load_phase(path, variable=None, orientation="v"):
    import numpy as np
    from .errors import FormatError

    if str(path).lower().endswith(".mat"):
        import scipy.io
        try:
            m = scipy.io.loadmat(str(path))
        except FileNotFoundError:
            raise FormatError(f"{path}: no such file") from None
        keys = [k for k in m if not k.startswith("__") and getattr(m[k], "ndim", 0) == 2]
        key = variable or (keys[0] if keys else None)
        if key not in m:
            raise FormatError(f"{path}: no 2-D variable {variable!r} (have {keys})")
        return np.asarray(m[key], dtype=np.float64)
    import h5py
    try:
        with h5py.File(str(path), "r") as f:
            return np.asarray(f[orientation]["phase"], dtype=np.float64)
    except (OSError, KeyError) as exc:
        raise FormatError(f"{path}: not a phase HDF5 with {orientation}/phase ({exc})") from None


def run(args) -> int:
    import numpy as np

    from . import load_system
    from .triangulate import fit_sphere, triangulate, triangulate_linear, write_ply
    from unwrap.patterns import projector_coordinate

    system = load_system(args.calibration if len(args.calibration) > 1 else args.calibration[0])
    phase = load_phase(args.phase, args.variable, args.orientation)
    if phase.shape != (system.camera.height, system.camera.width):
        print(f"calib reconstruct: error: phase is {phase.shape[1]}x{phase.shape[0]}, the camera is "
              f"{system.camera.width}x{system.camera.height}", file=sys.stderr)
        return 2
    valid = np.isfinite(phase) & (phase != 0)
    rows, cols = np.nonzero(valid)
    extent = system.projector.width if args.orientation == "v" else system.projector.height
    coord = projector_coordinate(phase[valid], args.frequency, extent)
    q = np.c_[cols, rows].astype(np.float64)
    fn = triangulate if args.method == "distortion" else triangulate_linear
    X, ok = fn(system, q, coord, args.orientation)
    write_ply(args.output, X[ok])
    print(f"{int(ok.sum())} points of {int(valid.sum())} valid pixels -> {args.output}")
    if args.sphere:
        c, r, res = fit_sphere(X[ok])
        print(f"sphere: centre {np.round(c, 4).tolist()} mm, radius {r:.5f} mm, "
              f"RMS {1000 * np.sqrt(np.mean(res ** 2)):.3f} um")
    return 0
