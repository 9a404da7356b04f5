"""The paper's Fig. 3 as a computation: reconstruct a sphere from every (calibration, phase) pair
and fit a sphere; the RMS of the fit residuals (um) fills a matrix.

Paper's published values (Liu et al., Fig. 3; dp-tpu README): real phase + real calibration
58.541 um, real phase + twin calibration 61.999 um, twin phase + real calibration 32.125 um,
twin phase + twin calibration 28.256 um (linear triangulation with K[R|T] of pose 1, no
distortion, least-squares sphere fit).

Two methods per cell: the paper's linear triangulation, and ours (distortion-aware), both from
``calib.triangulate``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import ReportError

PAPER_FIG3_UM = {("real", "real"): 58.541, ("real", "twin"): 61.999, ("twin", "real"): 32.125, ("twin", "twin"): 28.256}
"""(phase, calibration) -> sphere-fit RMS in um as published in the paper's Fig. 3."""


def load_phase(path, key: str | None = None) -> np.ndarray:
    """Absolute phase map (H, W) float64 from .mat (dp-tpu: ``phase3`` / ``phase``), .npy, or our HDF5
    (``v/phase``); 0, NaN and inf mark invalid pixels (returned as NaN)."""
    path = Path(path)
    if not path.exists():
        raise ReportError(f"{path}: no such phase file")
    suffix = path.suffix.lower()
    if suffix == ".mat":
        import scipy.io
        m = {k: v for k, v in scipy.io.loadmat(str(path)).items() if not k.startswith("__")}
        if key is None:
            arrays = [k for k, v in m.items() if isinstance(v, np.ndarray) and v.ndim == 2]
            if len(arrays) != 1:
                raise ReportError(f"{path}: expected one 2-D phase array, found {arrays}; name it with a key")
            key = arrays[0]
        phase = np.asarray(m[key], dtype=np.float64)
    elif suffix == ".npy":
        phase = np.load(path).astype(np.float64)
    elif suffix in (".h5", ".hdf5"):
        import h5py
        with h5py.File(path, "r") as f:
            k = key or "v/phase"
            if k not in f:
                raise ReportError(f"{path}: no dataset {k!r}")
            phase = np.asarray(f[k], dtype=np.float64)
    else:
        raise ReportError(f"{path}: unknown phase format (expected .mat, .npy, .h5)")
    if phase.ndim != 2:
        raise ReportError(f"{path}: phase must be 2-D, got shape {phase.shape}")
    phase[~np.isfinite(phase) | (phase == 0)] = np.nan
    return phase


def sphere_rms_um(system, phase: np.ndarray, frequency: float, method: str = "linear") -> dict:
    """Reconstruct the valid pixels of a vertical-fringe phase map and fit a sphere."""
    from calib.triangulate import fit_sphere, triangulate, triangulate_linear

    if phase.shape != (system.camera.height, system.camera.width):
        raise ReportError(f"phase map {phase.shape[::-1]} (W, H) does not match the camera image "
                          f"{system.camera.size}")
    valid = np.isfinite(phase)
    if valid.sum() < 100:
        raise ReportError(f"only {valid.sum()} valid phase pixels: no sphere to fit")
    v, u = np.nonzero(valid)
    q = np.stack([u, v], axis=1).astype(np.float64)
    u_p = phase[valid] * system.projector.width / (2 * np.pi * frequency)
    fn = triangulate_linear if method == "linear" else triangulate
    X, ok = fn(system, q, u_p)
    centre, radius, residuals = fit_sphere(X[ok])
    return {"rms_um": float(1000 * np.sqrt(np.mean(residuals ** 2))), "radius_mm": float(radius),
            "centre_mm": centre.tolist(), "points": int(ok.sum())}


def paper_key(label: str) -> str:
    """Phase/calibration label -> the paper's row/column ("real" or "twin"): "twin (synth)" -> "twin"."""
    return label.split(" ")[0]


def cross_reconstruction(systems: dict, phases: dict, frequency: float) -> list[dict]:
    """Rows ``{phase, calibration, method, rms_um, paper_um, ratio, ...}`` over every pair.

    Labels starting with "real" / "twin" are matched to the paper's Fig. 3 cell (linear method
    only: the paper's); ``ratio`` = ours / paper."""
    rows = []
    for pk, phase in phases.items():
        for ck, system in systems.items():
            for method in ("linear", "distortion-aware"):
                r = sphere_rms_um(system, phase, frequency, "linear" if method == "linear" else "ours")
                paper = PAPER_FIG3_UM.get((paper_key(pk), paper_key(ck))) if method == "linear" else None
                rows.append({"phase": pk, "calibration": ck, "method": method, **r, "paper_um": paper,
                             "ratio": r["rms_um"] / paper if paper else None})
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
    fig = sphere_matrix({f"{r['phase']} phase / {r['calibration']} cal / {r['method'][:6]}": r["rms_um"] for r in rows})
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
