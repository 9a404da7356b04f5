"""``calib reconstruct``: absolute phase + calibration -> point cloud (PLY).

    calib reconstruct --phase standardball_phase_real.mat --frequency 96 --calibration calibration.json -o ball.ply
    calib reconstruct --phase unwrap.h5 --calibration calibration.json -o out.ply     # v and/or h, frequency stored
    calib reconstruct --phase out/unwrap.h5 --calibration CAM.mat PRJ.mat --method linear -o out.ply

``--phase``: an HDF5 phase file of DESIGN.md (groups ``v``/``h``, dataset ``phase``, attribute
``frequency``), a MATLAB .mat (its 2-D array, or ``--variable``) or a .npy
(:func:`unwrap.phase_io.read_phase`). Pixels with phase 0 or NaN are invalid.
The frequency is the file's own where it stores one (``calib unwrap``'s ``unwrap.h5``; a
contradicting ``--frequency`` is refused), else ``--frequency``. A map with no valid pixel, one
decoded for another projector width, or one whose projector coordinates fall outside the
projector (a wrong frequency) is refused (:func:`calib.triangulate.points_from_phase`).
``--orientation`` (default ``auto``): with both orientations in the file, both projector
coordinates (:func:`calib.triangulate.triangulate_both`); with one, that one; a .mat/.npy map is
taken as columns (``v``) unless told ``h``. A warning says when the coordinate used is the
ill-conditioned one for this rig (:mod:`calib.coordinate_choice`: e.g. columns on a rig whose
baseline is mostly vertical).
``--method``: ``distortion`` (default; distortion-aware, iterated) or ``linear`` (K[R|t], no
distortion, as the paper). ``--sphere`` also fits a sphere and prints its RMS (um).
Exit codes: 0 success; 2 invalid input.
"""
from __future__ import annotations

from ..errors import CommandError
from ..outputs import claim

from ..argtypes import positive_float, positive_int

HELP = "absolute phase + calibration -> point cloud (PLY)"


def add_arguments(p):
    p.add_argument("--phase", required=True, help="absolute phase (.mat, .npy or DESIGN.md HDF5)")
    p.add_argument("--variable", help="variable name in a .mat file or dataset in an HDF5 file (default: the "
                                      ".mat's only 2-D array; the HDF5's ORIENTATION/phase)")
    p.add_argument("--frequency", type=positive_float, default=None,
                   help="periods across the projector pattern (default: the phase file's own, e.g. unwrap.h5's; "
                        "required for .mat/.npy maps, which do not store it)")
    p.add_argument("--orientation", choices=("auto", "v", "h", "both"), default="auto",
                   help="v: projector columns (u_p), h: rows (v_p), both: both coordinates; auto (default): "
                        "both when the file holds both, else the one it holds")
    p.add_argument("--calibration", nargs="+", required=True,
                   help="calibration file(s) (calib.load_system), or builtin: the built-in system")
    p.add_argument("--camera-size", nargs=2, type=positive_int, metavar=("W", "H"),
                   help="camera image size, for calibration files that do not store it")
    p.add_argument("--projector-size", nargs=2, type=positive_int, metavar=("W", "H"),
                   help="projector image size, for calibration files that do not store it")
    p.add_argument("--method", choices=("distortion", "linear"), default="distortion")
    p.add_argument("--sphere", action="store_true", help="fit a sphere and print its RMS")
    p.add_argument("-o", "--output", required=True, help="PLY path")
    p.add_argument("-q", "--quiet", action="store_true",
                   help="print only the sphere fit (--sphere), warnings and errors")


def phase_frequency(flag, stored, path) -> float:
    """The fringe frequency of the phase map: the file's own (``stored``), which a contradicting
    ``--frequency`` cannot override, else the flag; finite and > 0."""
    import math

    if stored is not None and flag is not None and not math.isclose(flag, float(stored), rel_tol=1e-9):
        raise CommandError(f"--frequency {flag:g} contradicts the frequency {float(stored):g} stored in {path}; "
                           "leave --frequency out to use the file's")
    frequency = float(stored) if stored is not None else flag
    if frequency is None:
        raise CommandError(f"--frequency is needed: {path} does not store the fringe frequency (periods across "
                           "the projector)")
    if not (math.isfinite(frequency) and frequency > 0):
        raise CommandError(f"--frequency: expected a number of periods > 0, got {frequency:g}")
    return frequency


def _wanted(args, stored: dict) -> list:
    """The orientations ``--orientation`` asks for among those the file holds (``stored``; {} for a
    .mat/.npy map, which is one orientation)."""
    if not stored:
        if args.orientation == "both":
            raise CommandError(f"{args.phase} holds one phase map: --orientation both needs an HDF5 file with v and h")
        return ["h" if args.orientation == "h" else "v"]
    wanted = [o for o in (("v", "h") if args.orientation in ("auto", "both") else (args.orientation,)) if o in stored]
    if not wanted or (args.orientation == "both" and len(wanted) < 2):
        raise CommandError(f"{args.phase} holds orientation(s) {sorted(stored)}; --orientation "
                           f"{args.orientation} needs {'v and h' if args.orientation == 'both' else args.orientation}")
    return wanted


def _phase_maps(args, system) -> tuple[dict, dict]:
    """({orientation: phase map}, {orientation: frequency}) the options ask for, each map checked
    against the calibration (camera size; the projector width it was decoded for)."""
    import numpy as np

    from unwrap.phase_io import phase_groups, read_phase

    groups = phase_groups(args.phase)
    maps, freqs = {}, {}
    for o in _wanted(args, groups):
        attrs = groups.get(o, {})
        freqs[o] = phase_frequency(args.frequency, attrs.get("frequency"), args.phase)
        extent = system.projector.width if o == "v" else system.projector.height
        if "width" in attrs and not np.isclose(float(attrs["width"]), extent):
            raise CommandError(f"{args.phase}: {o} decoded for a pattern {float(attrs['width']):g} px across, the "
                               f"calibration's projector is {extent} px: not this system's phase")
        maps[o] = read_phase(args.phase, args.variable, o)
        if maps[o].shape != (system.camera.height, system.camera.width):
            raise CommandError(f"{args.phase}: phase is {maps[o].shape[1]}x{maps[o].shape[0]}, the camera is "
                               f"{system.camera.width}x{system.camera.height}")
    return maps, freqs


def run(args) -> int:
    import numpy as np

    from calib import load_system
    from calib.triangulate import fit_sphere, points_from_phase, write_ply

    claim(args.output, "file", inputs=[args.phase, *args.calibration])
    from ..inputs import calibration_paths

    paths = calibration_paths(args.calibration)
    paths = paths[0] if len(paths) == 1 else paths
    system = load_system(paths, camera_size=args.camera_size, projector_size=args.projector_size)
    maps, freqs = _phase_maps(args, system)
    X, q, ok = points_from_phase(system, maps, freqs, args.orientation, args.method)
    if not ok.any():
        raise CommandError(f"{args.phase}: none of the {len(ok)} valid pixels triangulates with this calibration")
    used = "both coordinates" if len(maps) == 2 else ("columns (v)" if "v" in maps else "rows (h)")
    write_ply(args.output, X[ok])
    if not args.quiet:
        print(f"{int(ok.sum())} points of {len(q)} valid pixels ({used}) -> {args.output}")
    if args.sphere:
        c, r, res = fit_sphere(X[ok])
        print(f"sphere: centre {np.round(c, 4).tolist()} mm, radius {r:.5f} mm, "
              f"RMS {1000 * np.sqrt(np.mean(res ** 2)):.3f} um")
    return 0
