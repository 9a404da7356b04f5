"""Triangulation of camera pixels with projector coordinates (camera ray x projector plane), sphere fit.

Two methods, both float64 and vectorised over pixels:

- ``triangulate_linear``: what the paper did (Fig. 3): ``P = K [R | t]`` of camera and projector,
  no distortion; each point solves the 3x3 linear system of the two camera rows and the
  projector's ``u_p`` row.
- ``triangulate``: distortion-aware. The camera ray comes from undistorting the camera pixel;
  the projector constraint "u_p = const" is a curved surface when the projector has distortion,
  so it is linearised at the current point: the plane through the projector centre that
  contains the undistorted rays of ``(u_p, v_p)`` and ``(u_p, v_p + 1)``, with ``v_p`` the
  projector row of the current estimate. Iterated until ``v_p`` moves less than ``tol_px``.
  The same with ``orientation="h"`` for row coordinates ``v_p``.
- ``triangulate_both``: both projector coordinates (fringes captured in both orientations): the
  undistorted camera and projector rays, the point that best satisfies the four projection
  equations in pixel units (linear least squares in the undistorted image planes). It is as good
  as the better coordinate alone, whichever way the rig's baseline runs.

Which coordinate: a rig whose baseline lies nearly in the projector's column planes (mostly
vertical) triangulates badly from columns; :mod:`calib.coordinate_choice` measures it, and
:func:`triangulate`, :func:`triangulate_linear` and :func:`points_from_phase` warn (``calib``
logger) when asked for the ill-conditioned coordinate.

Points are returned in the world frame (mm); invalid inputs give NaN rows and a False mask.

From a phase map: :func:`points_from_phase` (every pixel with a valid absolute phase -> a world
point, by either method; given both orientations' maps, by both coordinates), :func:`sphere_from_phase` (those points -> a least-squares sphere, the
paper's Fig. 3 measure) and :func:`cross_reconstruction` (every pair of calibration and phase map).
This is the one phase -> points -> sphere path of the toolkit (``calib reconstruct``, the report's
ball matrix and the twin ball's pose all use it).

SYNOPSIS

    >>> import numpy as np
    >>> from calib import default_system
    >>> from calib.triangulate import triangulate
    >>> s = default_system()
    >>> X = np.array([[10.0, -5.0, 3.0]])
    >>> q, u = s.camera.project(X), s.projector.project(X)[:, 0]
    >>> P, ok = triangulate(s, q, u)
    >>> bool(np.allclose(P, X, atol=1e-6))
    True
"""
from __future__ import annotations

import numpy as np

from unwrap.safe_output import atomic_path

from .coordinate_choice import choose_orientation, warn_if_ill_conditioned
from .errors import TriangulationError

METHODS = ("distortion-aware", "linear")
"""Triangulation methods: ours (:func:`triangulate`) and the paper's (:func:`triangulate_linear`)."""
_ALIASES = {"ours": "distortion-aware", "distortion": "distortion-aware"}


def _check(q_cam, coord):
    q = np.asarray(q_cam, dtype=np.float64)
    c = np.asarray(coord, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 2 or c.shape != (len(q),):
        raise TriangulationError(f"expected q_cam (N, 2) and projector coordinates (N,), got {q.shape} and {c.shape}")
    return q, c


def projection_matrix(device) -> np.ndarray:
    """``K [R | t]`` (3, 4) of a device (world -> pixels, no distortion)."""
    return device.K @ np.c_[device.R, device.t]


def triangulate_linear(system, q_cam, coord, orientation: str = "v"):
    """Linear triangulation (the paper's): returns (points_world (N, 3), ok (N,))."""
    q, c = _check(q_cam, coord)
    warn_if_ill_conditioned(system, orientation)
    Pc, Pp = projection_matrix(system.camera), projection_matrix(system.projector)
    k = 0 if orientation == "v" else 1
    A = np.stack([q[:, :1] * Pc[2] - Pc[0], q[:, 1:] * Pc[2] - Pc[1], c[:, None] * Pp[2] - Pp[k]], axis=1)
    M, b = A[:, :, :3], -A[:, :, 3]
    ok = np.all(np.isfinite(M), axis=(1, 2)) & np.isfinite(b).all(axis=1)
    det = np.linalg.det(np.where(ok[:, None, None], M, np.eye(3)))
    ok &= np.abs(det) > 1e-12
    X = np.full((len(q), 3), np.nan)
    if ok.any():
        X[ok] = np.linalg.solve(M[ok], b[ok][..., None])[..., 0]
    return X, ok


def triangulate(system, q_cam, coord, orientation: str = "v", *, iterations: int = 20, tol_px: float = 1e-7):
    """Distortion-aware triangulation (module docstring): (points_world (N, 3), ok (N,))."""
    q, c = _check(q_cam, coord)
    warn_if_ill_conditioned(system, orientation)
    cam, prj = system.camera, system.projector
    rays, ok = cam.unproject(q)  # camera frame (x, y, 1)
    R_prj_cam = prj.R @ cam.R.T
    t_prj_cam = prj.t - R_prj_cam @ cam.t
    # start: projector's other coordinate at its principal point
    other = np.full(len(q), prj.cy if orientation == "v" else prj.cx)
    lam = np.full(len(q), np.nan)
    for _ in range(iterations):
        if orientation == "v":
            a, b = np.stack([c, other], -1), np.stack([c, other + 1.0], -1)
        else:
            a, b = np.stack([other, c], -1), np.stack([other + 1.0, c], -1)
        ra, oka = prj.unproject(a)
        rb, okb = prj.unproject(b)
        n = np.cross(ra, rb)                      # plane normal, projector frame
        n_cam = n @ R_prj_cam                          # R_prj_cam^T n, camera frame
        denom = np.sum(n_cam * rays, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = -(n @ t_prj_cam) / denom
        X_cam = rays * lam[:, None]
        p = prj.project_device(X_cam @ R_prj_cam.T + t_prj_cam)
        new_other = p[:, 1] if orientation == "v" else p[:, 0]
        step = np.abs(new_other - other)
        other = np.where(np.isfinite(new_other), new_other, other)
        ok_iter = oka & okb
        if np.nanmax(np.where(ok & ok_iter, step, 0.0), initial=0.0) < tol_px:
            break
    X_cam = rays * lam[:, None]
    ok = ok & ok_iter & np.isfinite(lam) & (lam > 0)
    X = (X_cam - cam.t) @ cam.R  # camera -> world: R^T (x - t)
    X[~ok] = np.nan
    return X, ok


def triangulate_both(system, q_cam, q_prj, *, undistort: bool = True):
    """Triangulate camera pixels with both projector coordinates (module docstring).

    ARGUMENTS: q_cam (N, 2) camera px; q_prj (N, 2) projector px ``(u_p, v_p)``; undistort: False
    ignores both devices' distortion (the linear model).
    RETURNED VALUE: (points_world (N, 3) mm, ok (N,)); NaN rows where not ok.
    """
    q = np.asarray(q_cam, dtype=np.float64)
    p = np.asarray(q_prj, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 2 or p.shape != q.shape:
        raise TriangulationError(f"expected q_cam (N, 2) and q_prj (N, 2), got {q.shape} and {p.shape}")
    rows, rhs, ok = [], [], np.ones(len(q), bool)
    for dev, pix in ((system.camera, q), (system.projector, p)):
        if undistort:
            rays, good = dev.unproject(pix)
            xy = rays[:, :2]
        else:
            xy, good = dev.pixels_to_normalized(pix), np.all(np.isfinite(pix), axis=1)
        ok &= good & np.all(np.isfinite(xy), axis=1)
        xy = np.where(ok[:, None], xy, 0.0)
        # x_n (r3 X + t3) = r1 X + t1, scaled by the focal lengths: residuals in pixels
        for k, f in ((0, dev.fx), (1, dev.fy)):
            rows.append(f * (xy[:, k:k + 1] * dev.R[2] - dev.R[k]))
            rhs.append(f * (dev.t[k] - xy[:, k] * dev.t[2]))
    A = np.stack(rows, axis=1)                   # (N, 4, 3)
    b = np.stack(rhs, axis=1)                    # (N, 4)
    AtA = np.einsum("nki,nkj->nij", A, A)
    Atb = np.einsum("nki,nk->ni", A, b)
    ok &= np.abs(np.linalg.det(AtA)) > 1e-12 * np.einsum("nii->n", AtA) ** 3
    X = np.full((len(q), 3), np.nan)
    if ok.any():
        X[ok] = np.linalg.solve(AtA[ok], Atb[ok][..., None])[..., 0]
    in_front = np.all([dev.world_to_device(np.where(ok[:, None], X, 0.0))[:, 2] > 0
                       for dev in (system.camera, system.projector)], axis=0)
    ok &= in_front
    X[~ok] = np.nan
    return X, ok


def _method(method: str):
    name = _ALIASES.get(method, method)
    if name not in METHODS:
        raise TriangulationError(f"method: expected one of {METHODS}, got {method!r}")
    return triangulate if name == "distortion-aware" else triangulate_linear


def _extent(system, orientation) -> int:
    return system.projector.width if orientation == "v" else system.projector.height


def _inside(coord, extent) -> np.ndarray:
    """Projector coordinates (px) no more than ``OUTSIDE_MARGIN_PX`` outside [-0.5, extent - 0.5)."""
    return (coord >= -0.5 - OUTSIDE_MARGIN_PX) & (coord < extent - 0.5 + OUTSIDE_MARGIN_PX)


def _coordinate_map(system, phase, frequency, orientation):
    """Projector coordinate (H, W) px of an absolute phase map (NaN where the phase is invalid).

    Refused (TriangulationError): a map that is not the camera's size, a frequency that is not
    > 0, a map with no valid pixel, and one of which more than ``MAX_OUTSIDE`` of the valid
    pixels map outside the projector (:func:`points_from_phase`)."""
    from unwrap.patterns import projector_coordinate

    phase = np.asarray(phase, dtype=np.float64)
    if phase.shape != (system.camera.height, system.camera.width):
        raise TriangulationError(f"phase map {phase.shape[1]}x{phase.shape[0]} (W x H) does not match the camera "
                                 f"image {system.camera.width}x{system.camera.height}")
    if frequency is None or not (np.isfinite(frequency) and frequency > 0):
        raise TriangulationError(f"frequency: expected periods across the projector > 0, got {frequency!r}")
    valid = np.isfinite(phase)
    if not valid.any():
        raise TriangulationError(f"the phase map ({orientation}) has no valid pixel (all NaN, inf or 0)")
    extent = _extent(system, orientation)
    coord = np.full(phase.shape, np.nan)
    coord[valid] = projector_coordinate(phase[valid], frequency, extent)
    outside = np.mean(~_inside(coord[valid], extent))
    if outside > MAX_OUTSIDE:
        raise TriangulationError(
            f"{100 * outside:.1f} % of the valid pixels map outside the projector ({orientation}: coordinates "
            f"{np.nanmin(coord):.1f} .. {np.nanmax(coord):.1f} px, the projector spans -0.5 .. {extent - 0.5} px at "
            f"{frequency:g} periods): wrong frequency, orientation or calibration?")
    return coord


def points_from_phase(system, phase, frequency, orientation: str = "v", method: str = "distortion-aware"):
    """World points of every camera pixel with a valid absolute phase.

    ARGUMENTS
    - system: calib.SystemModel.
    - phase: (H, W) absolute phase (rad), NaN (or inf) where invalid, the camera's image size; or
      ``{"v": map, "h": map}`` (either or both) for fringes along columns and along rows.
    - frequency: periods across the projector pattern (float), or ``{"v": f, "h": f}``.
    - orientation: "v" (u_p), "h" (v_p), "both" (:func:`triangulate_both`, the pixels valid in
      both maps) or "auto" (a dict holding both maps: "both"; one map: that one, with a warning
      when it is the ill-conditioned coordinate, :mod:`calib.coordinate_choice`).
    - method: "distortion-aware" (:func:`triangulate`) or "linear" (:func:`triangulate_linear`).
    RETURNED VALUE: (points_world (N, 3) mm, q_cam (N, 2) px, ok (N,)) over the N valid pixels,
    row-major; points are NaN where not ok.

    Refused (TriangulationError): a map with no valid pixel, a frequency that is not > 0, and a
    map of which more than ``MAX_OUTSIDE`` of the pixels give projector coordinates more than
    ``OUTSIDE_MARGIN_PX`` outside the projector's [-0.5, extent - 0.5) (a wrong frequency: too low
    a frequency stretches the coordinates beyond the pattern); the few such pixels of an accepted
    map are not ok.
    """
    fn = _method(method)
    maps = dict(phase) if isinstance(phase, dict) else {"v" if orientation in ("auto", "both") else orientation: phase}
    freqs = dict(frequency) if isinstance(frequency, dict) else {o: frequency for o in maps}
    bad = [o for o in maps if o not in ("v", "h")] + ([] if orientation in ("v", "h", "both", "auto") else [orientation])
    if bad:
        raise TriangulationError(f"orientation: expected 'v', 'h', 'both' or 'auto', got {bad[0]!r}")
    if orientation == "auto":
        orientation = choose_orientation(system, tuple(maps))
    needed = ("v", "h") if orientation == "both" else (orientation,)
    missing = [o for o in needed if o not in maps or o not in freqs]
    if missing:
        raise TriangulationError(f"orientation {orientation!r} needs the phase map and frequency of {missing}; "
                                 f"given maps {sorted(maps)}, frequencies {sorted(freqs)}")
    coords = {o: _coordinate_map(system, maps[o], freqs[o], o) for o in needed}
    valid = np.all([np.isfinite(c) for c in coords.values()], axis=0)
    v, u = np.nonzero(valid)
    q_cam = np.stack([u, v], axis=1).astype(np.float64)
    if orientation == "both":
        q_prj = np.stack([coords["v"][valid], coords["h"][valid]], axis=1)
        points, ok = triangulate_both(system, q_cam, q_prj, undistort=fn is triangulate)
    else:
        points, ok = fn(system, q_cam, coords[orientation][valid], orientation)
    for o in needed:       # the few pixels outside the projector of an accepted map
        ok = ok & _inside(coords[o][valid], _extent(system, o))
    points[~ok] = np.nan
    return points, q_cam, ok


#: Projector coordinates this far (px) outside the projector count as outside (points_from_phase).
OUTSIDE_MARGIN_PX = 1.0
#: Largest fraction of a phase map's pixels outside the projector that points_from_phase accepts.
MAX_OUTSIDE = 0.01


def sphere_from_phase(system, phase, frequency: float, orientation: str = "v", method: str = "linear",
                      min_points: int = 100) -> dict:
    """Reconstruct a phase map of a ball (:func:`points_from_phase`) and fit a sphere
    (:func:`fit_sphere`). Refused below ``min_points`` valid pixels or reconstructed points.

    RETURNED VALUE: ``{"rms_um", "radius_mm", "centre_mm" (world, list), "points"}``: the RMS of
    the fit residuals (um), the sphere, and the number of points fitted.
    """
    n_valid = int(np.isfinite(np.asarray(phase, dtype=np.float64)).sum())
    if n_valid < min_points:
        raise TriangulationError(f"only {n_valid} valid phase pixels: no sphere to fit (need {min_points})")
    points, _, ok = points_from_phase(system, phase, frequency, orientation, method)
    if ok.sum() < min_points:
        raise TriangulationError(f"only {int(ok.sum())} of {n_valid} valid pixels triangulate (need {min_points}): "
                                 "wrong calibration or frequency?")
    centre, radius, residuals = fit_sphere(points[ok])
    return {"rms_um": float(1000 * np.sqrt(np.mean(residuals ** 2))), "radius_mm": float(radius),
            "centre_mm": centre.tolist(), "points": int(ok.sum())}


def cross_reconstruction(systems: dict, phases: dict, frequency: float, orientation: str = "v") -> list[dict]:
    """The paper's Fig. 3 as a computation: :func:`sphere_from_phase` for every (phase map,
    calibration) pair and both methods. ``systems`` {label: SystemModel}, ``phases`` {label: (H, W)}.

    RETURNED VALUE: rows ``{"phase", "calibration", "method", "rms_um", "radius_mm", "centre_mm",
    "points"}``, phases outermost, then calibrations, then methods ("linear", "distortion-aware").
    """
    rows = []
    for pk, phase in phases.items():
        for ck, system in systems.items():
            for method in ("linear", "distortion-aware"):
                rows.append({"phase": pk, "calibration": ck, "method": method,
                             **sphere_from_phase(system, phase, frequency, orientation, method)})
    return rows


def fit_sphere(points):
    """Least-squares sphere: (centre (3,), radius, residuals (N,)) in the points' units.

    Algebraic fit for the start, then the geometric distance ``|p - c| - r`` minimised.
    """
    import scipy.optimize

    P = np.asarray(points, dtype=np.float64)
    P = P[np.all(np.isfinite(P), axis=1)]
    if len(P) < 4:
        raise TriangulationError(f"sphere fit needs >= 4 finite points, got {len(P)}")
    A = np.c_[2 * P, np.ones(len(P))]
    b = np.sum(P ** 2, axis=1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c0 = sol[:3]
    r0 = np.sqrt(max(sol[3] + c0 @ c0, 1e-12))

    def f(x):
        return np.linalg.norm(P - x[:3], axis=1) - x[3]

    res = scipy.optimize.least_squares(f, np.r_[c0, r0], method="lm", xtol=1e-15, ftol=1e-15)
    return res.x[:3], float(res.x[3]), f(res.x)


def write_ply(path, points, colors=None):
    """Binary little-endian PLY of finite points (N, 3) float64 -> float32 vertices (mm).

    float32 on disk is the PLY viewers' common type; 1e-7 relative (0.1 um at 1 m) is far below
    the reconstruction noise.
    """
    from pathlib import Path

    P = np.asarray(points, dtype=np.float64)
    keep = np.all(np.isfinite(P), axis=1)
    P = P[keep].astype("<f4")
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(P)}",
              "property float x", "property float y", "property float z"]
    data = P
    if colors is not None:
        C = np.asarray(colors)[keep].astype(np.uint8).reshape(len(P), -1)
        header += ["property uchar red", "property uchar green", "property uchar blue"]
        if C.shape[1] == 1:
            C = np.repeat(C, 3, axis=1)
        rec = np.zeros(len(P), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                      ("r", "u1"), ("g", "u1"), ("b", "u1")])
        rec["x"], rec["y"], rec["z"] = P.T
        rec["r"], rec["g"], rec["b"] = C.T
        data = rec
    header.append("end_header")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:   # a full disk leaves no truncated PLY
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        fh.write(np.ascontiguousarray(data).tobytes())
    return path
