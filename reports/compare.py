"""Side-by-side comparison of two calibrations (the paper's S2 vs S4 layout), with each difference
also in units of its standard deviation."""
from __future__ import annotations

import math

import numpy as np

from calib.rotation import angle_between_deg

from .inputs import INTRINSICS, CalibrationRecord


def _param(device, name):
    if name in ("fx", "fy", "cx", "cy", "skew"):
        return getattr(device, name)
    i = ("k1", "k2", "p1", "p2", "k3").index(name)
    return float(device.distortion[i]) if i < device.distortion.size else 0.0


#: Parameters a Blender twin cannot represent: it renders ideal pinholes (twin_mapping's
#: ``not_representable``), so a twin calibration finds them at 0 whatever the real lens has.
NOT_IN_TWIN = ("skew", "k1", "k2", "p1", "p2", "k3")


def _absent_from_twin(name, value, sigma) -> bool:
    """The twin's ``name`` is one the twin cannot hold and its estimate is consistent with 0."""
    if name not in NOT_IN_TWIN:
        return False
    return value == 0.0 or (sigma is not None and np.isfinite(sigma) and abs(value) <= 3 * sigma)


def parameter_rows(real: CalibrationRecord, twin: CalibrationRecord) -> list[dict]:
    """Rows ``{device, parameter, real, twin, difference, sigma, z, expected}``; sigma combines
    both sides' standard deviations (NaN where neither has one); z = difference / sigma;
    ``expected`` is True for skew and distortion terms the twin has at 0 (:data:`NOT_IN_TWIN`):
    there a real lens's value differs from the twin's by design, not by noise."""
    rows = []
    for kind in ("camera", "projector"):
        a, b = getattr(real.system, kind), getattr(twin.system, kind)
        for name in INTRINSICS:
            va, vb = _param(a, name), _param(b, name)
            sa = real.std.get(kind, {}).get(name)
            sb = twin.std.get(kind, {}).get(name)
            parts = [s for s in (sa, sb) if s is not None and np.isfinite(s)]
            sigma = math.sqrt(sum(s * s for s in parts)) if parts else float("nan")
            diff = vb - va
            rows.append({"device": kind, "parameter": name, "real": va, "twin": vb, "difference": diff,
                         "sigma_real": sa, "sigma_twin": sb, "sigma": sigma,
                         "z": diff / sigma if sigma and np.isfinite(sigma) and sigma > 0 else float("nan"),
                         "expected": _absent_from_twin(name, vb, sb)})
        rows.append({"device": kind, "parameter": "rotation (deg between)", "real": float("nan"), "twin": float("nan"),
                     "difference": angle_between_deg(a.R, b.R), "sigma": float("nan"), "z": float("nan"),
                     "sigma_real": None, "sigma_twin": None, "expected": False})
        for j, axis in enumerate("xyz"):
            rows.append({"device": kind, "parameter": f"t{axis} (mm)", "real": float(a.t[j]), "twin": float(b.t[j]),
                         "difference": float(b.t[j] - a.t[j]), "sigma": float("nan"), "z": float("nan"),
                         "sigma_real": None, "sigma_twin": None, "expected": False})
    return rows


def rig_rows(real: CalibrationRecord, twin: CalibrationRecord) -> list[dict]:
    """The projector's pose relative to the camera (baseline), which does not depend on the choice
    of world frame: rotation angle and translation of ``x_prj = R x_cam + t``."""
    out = []
    for rec in (real, twin):
        c, p = rec.system.camera, rec.system.projector
        R = p.R @ c.R.T
        t = p.t - R @ c.t
        out.append({"label": rec.label, "R_prj_cam": R, "t_prj_cam": t, "baseline_mm": float(np.linalg.norm(t))})
    out.append({"label": "twin - real", "rotation_deg": angle_between_deg(out[0]["R_prj_cam"], out[1]["R_prj_cam"]),
                "t_diff_mm": (out[1]["t_prj_cam"] - out[0]["t_prj_cam"]).tolist(),
                "baseline_diff_mm": out[1]["baseline_mm"] - out[0]["baseline_mm"]})
    return out
