"""Which projector coordinate to triangulate with: the rig's geometry decides, not a default.

A camera pixel with one projector coordinate is triangulated as the camera ray met by the
projector's surface of constant coordinate: a column plane ``u_p = const`` (orientation ``v``,
fringes along columns) or a row plane ``v_p = const`` (``h``). Every column plane contains the
projector's own vertical direction through its centre; when the baseline (camera centre ->
projector centre) lies nearly in those planes - a rig whose baseline is mostly vertical in the
projector's frame - a camera ray runs almost inside the column plane it meets, and a small error
in ``u_p`` moves the point far along the ray. Rows are then the well-conditioned coordinate.

The measure: the sensitivity ``|d coord / d depth|`` (projector px per mm of depth along the
camera ray), the median over a 5 x 5 grid of camera pixels at the rig's working depth. A
coordinate error of ``e`` px then moves a point by ``e / sensitivity`` mm along its ray, so the
ratio of the two sensitivities is the ratio of the two reconstructions' depth noise for equal
coordinate noise. A coordinate is *ill-conditioned* when its sensitivity is below
``ILL_CONDITIONED_RATIO`` (one half) of the other's: its depth noise is more than twice as large.

Working depth: the world origin's depth in the camera when it lies in front of it (a calibration
from board views puts the world at the first board pose), else the depth where the camera's and
the projector's optical axes pass closest, else five baselines.

SYNOPSIS

    >>> from calib import default_system
    >>> from calib.coordinate_choice import coordinate_conditioning
    >>> c = coordinate_conditioning(default_system())
    >>> c.better, c.ill_conditioned("v")
    ('v', False)
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .errors import TriangulationError

ILL_CONDITIONED_RATIO = 0.5
"""A coordinate whose depth sensitivity is below this fraction of the other's is ill-conditioned."""

ORIENTATION_NAMES = {"v": "projector columns (u_p, fringes along columns)",
                     "h": "projector rows (v_p, fringes along rows)"}

log = logging.getLogger(__name__)


@dataclass
class CoordinateConditioning:
    """How well each projector coordinate fixes depth along the camera rays of a rig.

    - sensitivity_px_per_mm: {"v": ..., "h": ...} median ``|d coord / d depth|`` (projector px per
      mm along the camera ray) over a grid of camera pixels at ``depth_mm``.
    - depth_mm: the working depth used (camera frame z, mm); depth_source: how it was chosen.
    - better: "v" or "h", the coordinate with the larger sensitivity.
    """

    sensitivity_px_per_mm: dict
    depth_mm: float
    depth_source: str
    better: str

    def ratio(self, orientation: str) -> float:
        """Sensitivity of ``orientation`` over the better one's (1 for the better one)."""
        s = self.sensitivity_px_per_mm
        return float(s[orientation] / max(s[self.better], 1e-300))

    def ill_conditioned(self, orientation: str) -> bool:
        """True when ``orientation``'s depth noise is more than 1 / ILL_CONDITIONED_RATIO times the other's."""
        return self.ratio(orientation) < ILL_CONDITIONED_RATIO

    def describe(self, orientation: str) -> str:
        s = self.sensitivity_px_per_mm
        return (f"{ORIENTATION_NAMES[orientation]}: {s[orientation]:.3g} projector px per mm of depth at "
                f"{self.depth_mm:.0f} mm ({self.depth_source}), {self.ratio(orientation):.2f} x that of "
                f"{ORIENTATION_NAMES[self.better]} ({s[self.better]:.3g} px/mm)")


def _working_depth(system) -> tuple[float, str]:
    cam, prj = system.camera, system.projector
    z_origin = float(cam.t[2])
    if z_origin > 0 and np.linalg.norm(cam.t) > 1e-6:
        return z_origin, "depth of the world origin"
    R_pc = prj.R @ cam.R.T
    t_pc = prj.t - R_pc @ cam.t
    c_p = -R_pc.T @ t_pc                       # projector centre, camera frame
    d_c, d_p = np.array([0.0, 0.0, 1.0]), R_pc.T @ np.array([0.0, 0.0, 1.0])
    b = float(np.linalg.norm(c_p))
    # closest approach of the axes s d_c and c_p + r d_p
    A = np.array([[d_c @ d_c, -d_c @ d_p], [d_c @ d_p, -d_p @ d_p]])
    if abs(np.linalg.det(A)) > 1e-9:
        s, r = np.linalg.solve(A, [d_c @ c_p, d_p @ c_p])
        if s > 0 and r > 0 and s < 1e3 * max(b, 1.0):
            return float(s), "where the optical axes pass closest"
    if b <= 0:
        raise TriangulationError("camera and projector share one centre: nothing can be triangulated")
    return 5.0 * b, "five baselines (the optical axes do not converge)"


def coordinate_conditioning(system, depth_mm: float | None = None) -> CoordinateConditioning:
    """Depth sensitivity of both projector coordinates for ``system`` (module docstring)."""
    cam, prj = system.camera, system.projector
    depth, source = (float(depth_mm), "given") if depth_mm is not None else _working_depth(system)
    if not (np.isfinite(depth) and depth > 0):
        raise TriangulationError(f"working depth must be finite and > 0 mm, got {depth!r}")
    W, H = cam.size
    gx, gy = np.meshgrid(np.linspace(0.1, 0.9, 5) * (W - 1), np.linspace(0.1, 0.9, 5) * (H - 1))
    rays, ok = cam.unproject(np.stack([gx.ravel(), gy.ravel()], axis=1))
    R_pc = prj.R @ cam.R.T
    t_pc = prj.t - R_pc @ cam.t
    dz = 1e-3 * depth
    q = [prj.project_device((rays * z) @ R_pc.T + t_pc) for z in (depth - dz, depth + dz)]
    deriv = np.abs(q[1] - q[0]) / (2 * dz)
    good = ok & np.all(np.isfinite(deriv), axis=1)
    if not good.any():
        raise TriangulationError(f"no camera ray reaches the projector's image at {depth:.0f} mm depth: "
                                 "is the calibration a camera + projector rig?")
    sens = {"v": float(np.median(deriv[good, 0])), "h": float(np.median(deriv[good, 1]))}
    return CoordinateConditioning(sens, depth, source, "v" if sens["v"] >= sens["h"] else "h")


def choose_orientation(system, available=("v", "h")) -> str:
    """``"both"`` when both coordinates are available, else the one available; a warning on the
    ``calib`` logger when that one is ill-conditioned (:func:`warn_if_ill_conditioned`)."""
    available = tuple(o for o in ("v", "h") if o in available)
    if not available:
        raise TriangulationError("no projector coordinate given (expected 'v' and/or 'h')")
    if len(available) == 2:
        return "both"
    warn_if_ill_conditioned(system, available[0])
    return available[0]


def warn_if_ill_conditioned(system, orientation: str) -> CoordinateConditioning:
    """Log a warning (``calib`` logger) when ``orientation`` is the ill-conditioned coordinate of
    ``system``; returns the conditioning."""
    if orientation not in ORIENTATION_NAMES:
        raise TriangulationError(f"orientation: expected 'v' or 'h', got {orientation!r}")
    c = coordinate_conditioning(system)
    if c.ill_conditioned(orientation):
        log.warning(f"ill-conditioned coordinate: triangulating with {c.describe(orientation)}: depth errors are "
                    f"{1 / c.ratio(orientation):.1f} x larger than with the other coordinate; capture "
                    f"{'rows (h)' if orientation == 'v' else 'columns (v)'} (or both) for this rig")
    return c


__all__ = ["ILL_CONDITIONED_RATIO", "CoordinateConditioning", "coordinate_conditioning", "choose_orientation",
           "warn_if_ill_conditioned"]
