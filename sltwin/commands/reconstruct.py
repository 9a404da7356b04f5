"""``calib reconstruct``: absolute phase + calibration -> point cloud (PLY).

    calib reconstruct --phase standardball_phase_real.mat --frequency 96 --calibration calibration.json -o ball.ply
    calib reconstruct --phase phase.h5 --frequency 48 --calibration CAM.mat PRJ.mat --method linear -o out.ply

``--phase``: an HDF5 phase file of DESIGN.md (``--orientation``'s group, dataset ``phase``), a
MATLAB .mat (its 2-D array, or ``--variable``) or a .npy (:func:`unwrap.phase_io.read_phase`).
Pixels with phase 0 or NaN are invalid.
``--method``: ``distortion`` (default; distortion-aware, iterated) or ``linear`` (K[R|t], no
distortion, as the paper). ``--sphere`` also fits a sphere and prints its RMS (um).
Exit codes: 0 success; 2 invalid input.
"""
from __future__ import annotations

from ..errors import CommandError

HELP = "absolute phase + calibration -> point cloud (PLY)"


def add_arguments(p):
    p.add_argument("--phase", required=True, help="absolute phase (.mat or DESIGN.md HDF5)")
    p.add_argument("--variable", help="variable name in a .mat file or dataset in an HDF5 file (default: the "
                                      ".mat's only 2-D array; the HDF5's ORIENTATION/phase)")
    p.add_argument("--frequency", type=float, required=True, help="periods across the projector pattern")
    p.add_argument("--orientation", choices=("v", "h"), default="v",
                   help="v: fringes along projector columns (u_p), h: rows (v_p)")
    p.add_argument("--calibration", nargs="+", required=True, help="calibration file(s) (calib.load_system)")
    p.add_argument("--method", choices=("distortion", "linear"), default="distortion")
    p.add_argument("--sphere", action="store_true", help="fit a sphere and print its RMS")
    p.add_argument("-o", "--output", required=True, help="PLY path")


def run(args) -> int:
    import numpy as np

    from calib import load_system
    from calib.triangulate import fit_sphere, triangulate, triangulate_linear, write_ply
    from unwrap.patterns import projector_coordinate
    from unwrap.phase_io import read_phase

    system = load_system(args.calibration if len(args.calibration) > 1 else args.calibration[0])
    phase = read_phase(args.phase, args.variable, args.orientation)
    if phase.shape != (system.camera.height, system.camera.width):
        raise CommandError(f"phase is {phase.shape[1]}x{phase.shape[0]}, the camera is "
                           f"{system.camera.width}x{system.camera.height}")
    valid = np.isfinite(phase)
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
