"""The paper's Fig. 3 laid out: the sphere-fit RMS of the reconstructed ball for every
(calibration, phase) pair, computed by :func:`calib.triangulate.cross_reconstruction` (the
paper's linear triangulation and our distortion-aware one), beside the paper's published values
(:data:`twin_mapping.paper_tables.FIG3_SPHERE_RMS_UM`: real phase + real calibration 58.541 um,
real + twin 61.999 um, twin + real 32.125 um, twin + twin 28.256 um; its linear method).
"""
from __future__ import annotations

from calib.triangulate import cross_reconstruction as _cross_reconstruction
from twin_mapping.paper_tables import FIG3_SPHERE_RMS_UM


def paper_key(label: str) -> str:
    """Phase/calibration label -> the paper's row/column ("real" or "twin"): "twin (synth)" -> "twin"."""
    return label.split(" ")[0]


def cross_reconstruction(systems: dict, phases: dict, frequency: float) -> list[dict]:
    """Rows ``{phase, calibration, method, rms_um, paper_um, ratio, ...}`` over every pair
    (:func:`calib.triangulate.cross_reconstruction`), with the paper's Fig. 3 value beside each
    linear-method cell whose labels start with "real" / "twin"; ``ratio`` = ours / paper."""
    rows = _cross_reconstruction(systems, phases, frequency)
    for r in rows:
        paper = FIG3_SPHERE_RMS_UM.get((paper_key(r["phase"]), paper_key(r["calibration"]))) \
            if r["method"] == "linear" else None
        r.update(paper_um=paper, ratio=r["rms_um"] / paper if paper else None)
    return rows


def fig3_grid(rows) -> list[list]:
    """The matrix as Fig. 3 lays it out: one line per (phase, method), calibrations side by side,
    the paper's values beside (linear method)."""
    cals = list(dict.fromkeys(r["calibration"] for r in rows))
    cell = {(r["phase"], r["calibration"], r["method"]): r for r in rows}
    grid = []
    for pk in dict.fromkeys(r["phase"] for r in rows):
        for method in ("linear", "distortion-aware"):
            line = [pk, method] + [cell[(pk, c, method)]["rms_um"] if (pk, c, method) in cell else "-" for c in cals]
            line += [cell[(pk, c, method)]["paper_um"] or "-" if (pk, c, method) in cell else "-" for c in cals]
            grid.append(line)
    return [["phase", "method"] + [f"{c} cal. (um)" for c in cals] + [f"paper, {c} cal. (um)" for c in cals], grid]


def sphere_section(systems: dict, phases: dict, frequency: float, extra_rows=()):
    """Report section blocks for the sphere matrix; ``extra_rows`` (e.g. the twin render's floor)
    are appended to the table and the returned rows as they are."""
    from .figures import sphere_matrix

    rows = cross_reconstruction(systems, phases, frequency) + list(extra_rows)
    table = [[r["phase"], r["calibration"], r["method"], r["rms_um"], r["paper_um"] if r["paper_um"] else "-",
              r["ratio"] if r.get("ratio") else "-",
              "! more than 20 % from the paper" if r.get("ratio") and abs(r["ratio"] - 1) > 0.2 else "",
              r["radius_mm"], r["points"]] for r in rows]
    fig = sphere_matrix({f"{r['phase']} phase / {r['calibration']} cal / {r['method']}": r["rms_um"] for r in rows})
    header, grid = fig3_grid([r for r in rows if r["calibration"] in systems])
    return rows, [("p", f"Sphere-fit RMS of the reconstructed ball (f = {frequency:g} periods), for every pair of "
                        "phase map and calibration; 'linear' is the paper's method (K[R|T], no distortion), "
                        "'distortion-aware' is ours. Paper values from its Fig. 3 (its linear method). Phase 'twin' "
                        "is the twin phase file given (dp-tpu: the paper's Blender render), 'twin (synth)' ours, "
                        "rendered at the real ball's fitted pose."),
                  ("table", header, grid),
                  ("table", ["phase", "calibration", "method", "RMS (um)", "paper (um)", "ours / paper", "",
                             "radius (mm)", "points"], table),
                  ("figure", fig, "sphere-fit RMS per (phase, calibration, method)")]
