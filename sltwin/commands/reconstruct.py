"""``calib reconstruct``: absolute phase + calibration -> point cloud (PLY).

    calib reconstruct --phase standardball_phase_real.mat --frequency 96 --calibration calibration.json -o ball.ply
    calib reconstruct --phase out/unwrap.h5 --calibration CAM.mat PRJ.mat --method linear -o out.ply

``--phase``: an HDF5 phase file of DESIGN.md (``--orientation``'s group, dataset ``phase``), a
MATLAB .mat (its 2-D array, or ``--variable``) or a .npy (:func:`unwrap.phase_io.read_phase`).
Pixels with phase 0 or NaN are invalid. The frequency is the file's own where it stores one
(``calib unwrap``'s ``unwrap.h5``; a contradicting ``--frequency`` is refused), else ``--frequency``.
A map with no valid pixel, or whose projector coordinates fall outside the projector (a wrong
frequency), is refused (:func:`calib.triangulate.points_from_phase`).
``--method``: ``distortion`` (default; distortion-aware, iterated) or ``linear`` (K[R|t], no
distortion, as the paper). ``--sphere`` also fits a sphere and prints its RMS (um).
Exit codes: 0 success; 2 invalid input.
"""
from __future__ import annotations

from ..errors import CommandError
from ..outputs import output_file

HELP = "absolute phase + calibration -> point cloud (PLY)"


def add_arguments(p):
    p.add_argument("--phase", required=True, help="absolute phase (.mat or DESIGN.md HDF5)")
    p.add_argument("--variable", help="variable name in a .mat file or dataset in an HDF5 file (default: the "
                                      ".mat's only 2-D array; the HDF5's ORIENTATION/phase)")
    p.add_argument("--frequency", type=float, default=None,
                   help="periods across the projector pattern (default: the phase file's own, e.g. unwrap.h5's; "
                        "required for .mat/.npy maps, which do not store it)")
    p.add_argument("--orientation", choices=("v", "h"), default="v",
                   help="v: fringes along projector columns (u_p), h: rows (v_p)")
    p.add_argument("--calibration", nargs="+", required=True, help="calibration file(s) (calib.load_system)")
    p.add_argument("--method", choices=("distortion", "linear"), default="distortion")
    p.add_argument("--sphere", action="store_true", help="fit a sphere and print its RMS")
    p.add_argument("-o", "--output", required=True, help="PLY path")


def phase_frequency(flag, stored, path) -> float:
    """The fringe frequency of the phase map: the file's own (``stored``), which a contradicting
    ``--frequency`` cannot override, else the flag; finite and > 0."""
    import math

    if stored is not None and flag is not None and not math.isclose(flag, float(stored), rel_tol=1e-9):
        raise CommandError(f"--frequency {flag:g} contradicts the frequency {float(stored):g} stored in {path}; "
                           "leave --frequency out to use the file's")
    frequency = float(stored) if stored is not None else flag
    if frequency is None:
        raise CommandError(f"--frequency: {path} does not store the fringe frequency (periods across the "
                           "projector); give it")
    if not (math.isfinite(frequency) and frequency > 0):
        raise CommandError(f"--frequency: expected a number of periods > 0, got {frequency:g}")
    return frequency


def run(args) -> int:
    import numpy as np

    from calib import load_system
    from calib.triangulate import fit_sphere, points_from_phase, write_ply
    from unwrap.phase_io import phase_attributes, read_phase

    output_file(args.output)
    system = load_system(args.calibration if len(args.calibration) > 1 else args.calibration[0])
    attrs = phase_attributes(args.phase, args.orientation)
    frequency = phase_frequency(args.frequency, attrs.get("frequency"), args.phase)
    phase = read_phase(args.phase, args.variable, args.orientation)
    if phase.shape != (system.camera.height, system.camera.width):
        raise CommandError(f"{args.phase}: phase is {phase.shape[1]}x{phase.shape[0]}, the camera is "
                           f"{system.camera.width}x{system.camera.height}")
    extent = system.projector.width if args.orientation == "v" else system.projector.height
    if "width" in attrs and not np.isclose(float(attrs["width"]), extent):
        raise CommandError(f"{args.phase}: decoded for a pattern {float(attrs['width']):g} px across, the "
                           f"calibration's projector is {extent} px ({args.orientation}): not this system's phase")
    method = "distortion-aware" if args.method == "distortion" else "linear"
    X, _, ok = points_from_phase(system, phase, frequency, args.orientation, method)
    if not ok.any():
        raise CommandError(f"{args.phase}: none of the {len(ok)} valid pixels triangulates with this calibration")
    write_ply(args.output, X[ok])
    print(f"{int(ok.sum())} points of {len(ok)} valid pixels -> {args.output}")
    if args.sphere:
        c, r, res = fit_sphere(X[ok])
        print(f"sphere: centre {np.round(c, 4).tolist()} mm, radius {r:.5f} mm, "
              f"RMS {1000 * np.sqrt(np.mean(res ** 2)):.3f} um")
    return 0
