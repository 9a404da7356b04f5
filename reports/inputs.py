"""Inputs of the twin-equivalence report: two calibration records
(:mod:`calib.io.record`, re-exported here) and the check that they can be compared."""
from __future__ import annotations

import numpy as np

from calib.io.record import INTRINSICS, CalibrationRecord, load_calibration_record  # noqa: F401

from .errors import ReportError


def check_comparable(real: CalibrationRecord, twin: CalibrationRecord) -> None:
    """Refuse a comparison of systems that cannot be compared (sizes differ, units differ)."""
    for kind in ("camera", "projector"):
        a, b = getattr(real.system, kind), getattr(twin.system, kind)
        if a.size != b.size:
            raise ReportError(f"{kind} image sizes differ: {real.label} {a.size} vs {twin.label} {b.size}; "
                              "a twin must have the real system's image sizes")
    if real.views and twin.views and len(real.views[0].points_board) and len(twin.views[0].points_board):
        ext_r = np.ptp(real.views[0].points_board[:, :2])
        ext_t = np.ptp(twin.views[0].points_board[:, :2])
        if ext_t > 0 and not 0.2 < ext_r / ext_t < 5:
            raise ReportError(f"board extents differ by a factor {ext_r / ext_t:.1f} ({real.label} {ext_r:.4g}, "
                              f"{twin.label} {ext_t:.4g}): different length units?")
