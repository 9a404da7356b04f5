"""The paper's printed tables S2/S3 and eqs. S1-S3, and how our mapping compares with them.

The printed values themselves (tables S2, S3; eqs. S1-S3, with their source) are in
:mod:`twin_mapping.paper_tables`, with every other number the toolkit takes from the paper.

``compare_with_table_s3`` classifies every printed value: it reproduces when our full-precision
value, truncated toward zero or rounded to the printed decimals, gives the printed digits;
otherwise it is flagged, with a diagnosis where one can be found (a dropped digit, a rounded
datasheet value), never silently replaced.
"""
from __future__ import annotations

import math

import numpy as np

from calib.rotation import nearest_rotation, rotation_defects

from .paper_tables import EQ_S1_S3, TABLE_S2_ROTATIONS, TABLE_S3  # noqa: F401  (re-exported)

def _decimals(printed: str) -> int:
    return len(printed.split(".")[1]) if "." in printed else 0


def _truncated(value: float, decimals: int) -> str:
    scale = 10 ** decimals
    return f"{math.trunc(value * scale) / scale:.{decimals}f}"


def _dropped_digit(full: str, printed: str) -> int | None:
    """Index of the digit of ``full`` whose removal gives ``printed``, or None."""
    for i, ch in enumerate(full):
        if ch.isdigit() and full[:i] + full[i + 1:] == printed:
            return i
    return None


def classify(value: float, printed: str) -> tuple[str, str]:
    """(status, note) of one printed value against our full-precision value."""
    d = _decimals(printed)
    trunc, rounded = _truncated(value, d), f"{value:.{d}f}"
    p = printed.lstrip("+")
    if p in (trunc, rounded) or (p.replace("-", "") in (trunc.replace("-", ""), rounded.replace("-", ""))
                                 and float(p) == 0.0):
        how = ("truncated" if p == trunc and p != rounded else "rounded" if p == rounded and p != trunc
                   else "rounded or truncated (same digits)")
        return "reproduces", f"printed value is ours {how} to {d} decimals"
    for candidate in (trunc, rounded):
        i = _dropped_digit(candidate, p)
        if i is not None:
            return "INCONSISTENT", (f"a digit is missing in print: ours {candidate}, printed {p} "
                                    f"(digit '{candidate[i]}' dropped)")
    return "DOES NOT REPRODUCE", f"ours {rounded}, printed {p}"


def compare_with_table_s3(twin: dict) -> list[dict]:
    """Rows ``{device, quantity, axis, ours, printed, difference, status, note}`` for S3 and eqs. S1-S3."""
    rows = []
    axes = {"rotation_euler_deg": "xyz", "location_mm": "xyz", "focal_length_mm": "xy",
            "pixel_pitch_um": "xy"}
    for device in ("camera", "projector"):
        tw = twin[device]
        ours = {"rotation_euler_deg": tw["rotation_euler_deg"], "location_mm": tw["location_mm"],
                "focal_length_mm": [tw["focal_length_mm"], tw.get("focal_length_y_mm")],
                "pixel_pitch_um": tw.get("pixel_pitch_um", [])}
        printed_all = dict(TABLE_S3[device])
        printed_all.update(EQ_S1_S3[device])
        for quantity, printed_values in printed_all.items():
            for i, printed in enumerate(printed_values):
                value = float(ours[quantity][i])
                status, note = classify(value, printed)
                if quantity == "pixel_pitch_um" and status != "reproduces":
                    note += _pitch_diagnosis(tw, i, printed)
                if quantity == "focal_length_mm" and device == "projector" and status != "reproduces":
                    note += _projector_focal_diagnosis(tw, printed)
                rows.append({"device": device, "quantity": quantity, "axis": axes[quantity][i],
                             "ours": value, "printed": float(printed), "printed_text": printed,
                             "difference": value - float(printed), "status": status, "note": note})
    return rows


def _pitch_diagnosis(tw: dict, axis: int, printed: str) -> str:
    size_mm = tw["sensor_size_mm"][axis]
    n = size_mm / float(printed) * 1000.0
    return (f"; the printed pitch is {size_mm} mm / {n:.0f} px, while the device has "
            f"{tw['resolution'][axis]} px along this axis")


def _projector_focal_diagnosis(tw: dict, printed: str) -> str:
    fx_px = tw["focal_length_mm"] / tw["pixel_pitch_um"][0] * 1000.0
    alt = fx_px * float(EQ_S1_S3["projector"]["pixel_pitch_um"][0]) / 1000.0
    status, _ = classify(alt, printed)
    if status == "reproduces":
        return (f"; it reproduces ({alt:.5f} mm) with eq. S2's rounded pitch "
                f"{EQ_S1_S3['projector']['pixel_pitch_um'][0]} um instead of 10.8 mm / 912")
    return ""


def check_table_s2_rotations(full_precision: dict | None = None) -> list[dict]:
    """Orthonormality of the printed S2 rotations, the SVD repair, and the entries whose sign or
    value disagrees with the full-precision matrices (when given, ``{device: R}``)."""
    out = []
    for device, R in TABLE_S2_ROTATIONS.items():
        R = np.asarray(R)
        err, det = rotation_defects(R)
        R_fix, moved = nearest_rotation(R)
        row = {"device": device, "max_orthonormality_error": err, "det": det, "repair_moved_deg": moved}
        if full_precision is not None:
            full = np.asarray(full_precision[device])
            bad = np.argwhere(np.abs(full - R) > 0.0051)  # beyond 3-decimal rounding (+ slack)
            row["entries_off"] = [{"row": int(i) + 1, "col": int(j) + 1, "printed": float(R[i, j]),
                                   "full_precision": float(full[i, j])} for i, j in bad]
            Rs = R.copy()
            for i, j in bad:
                if abs(full[i, j] + R[i, j]) <= 0.0051:
                    Rs[i, j] = -R[i, j]
            row["det_after_sign_fix"] = float(np.linalg.det(Rs))
        out.append(row)
    return out
