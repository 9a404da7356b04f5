"""Inputs of the twin-equivalence report: a calibration with its uncertainties and observations.

``load_calibration_record(paths)`` reads
- a Bouguet ``.mat`` pair (camera, projector): parameters of board pose 1 as world, the toolbox's
  3-sigma errors (divided by 3 here), per-view board points and pixels of both devices, and the
  reprojection error std;
- a ``calibration.json`` (DESIGN.md keys; ``uncertainties_1sigma`` and ``residuals`` when
  ``calib run`` wrote them), with ``observations.json`` beside it when present.
Every file's SHA-256 is recorded for the report's run facts.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calib.io import load_system
from calib.system import SystemModel

from .errors import ReportError

INTRINSICS = ("fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3")


@dataclass
class ViewObservations:
    """One board view: board points (N,3) mm, and per device the observed pixels (N,2) (NaN where
    a device did not see a point) and the board -> device pose of that view when known."""

    name: str
    points_board: np.ndarray
    pixels: dict
    poses: dict = field(default_factory=dict)


@dataclass
class CalibrationRecord:
    label: str
    system: SystemModel
    std: dict                       # {device: {param: 1-sigma}}; may be empty
    views: list                     # [ViewObservations]; may be empty
    residual_rms_px: dict           # {device: [rms per view]}; may be empty
    files: dict                     # {path: sha256}
    kind: str                       # "bouguet" or "calibration.json"


def sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _from_bouguet(paths, label) -> CalibrationRecord:
    from calib.io.bouguet import read_bouguet

    cam, prj = read_bouguet(paths[0]), read_bouguet(paths[1])
    system = load_system(paths)
    std = {}
    for kind, r in (("camera", cam), ("projector", prj)):
        s = {"fx": r.fc_error[0] / 3, "fy": r.fc_error[1] / 3, "cx": r.cc_error[0] / 3, "cy": r.cc_error[1] / 3,
             "skew": r.alpha_c_error * r.fc[0] / 3}
        for i, name in enumerate(("k1", "k2", "p1", "p2", "k3")[:r.kc_error.size]):
            s[name] = r.kc_error[i] / 3
        std[kind] = {k: float(v) for k, v in s.items() if np.isfinite(v)}
    views, rms = [], {"camera": [], "projector": []}
    for i in range(len(cam.points_board)):
        if not np.allclose(cam.points_board[i], prj.points_board[i]):
            raise ReportError(f"{paths[0]} and {paths[1]}: view {i + 1} has different board points in the two files")
        poses = {"camera": (cam.R_dev_board[i], cam.t_dev_board[i]), "projector": (prj.R_dev_board[i], prj.t_dev_board[i])}
        views.append(ViewObservations(f"pose {i + 1}", cam.points_board[i],
                                      {"camera": cam.points_px[i], "projector": prj.points_px[i]}, poses))
        for kind, r in (("camera", cam), ("projector", prj)):
            q = r.device(kind, i).project(r.points_board[i])
            rms[kind].append(float(np.sqrt(np.mean(np.sum((q - r.points_px[i]) ** 2, axis=1)))))
    return CalibrationRecord(label, system, std, views, rms, {str(p): sha256(p) for p in paths}, "bouguet")


def _from_json(path: Path, label) -> CalibrationRecord:
    system = load_system(path)
    d = json.loads(path.read_text())
    std = {}
    for kind, s in (d.get("uncertainties_1sigma") or {}).items():
        if kind in ("camera", "projector") and isinstance(s, dict):
            std[kind] = {k: float(v) for k, v in s.items() if isinstance(v, (int, float))}
    rms = {}
    res = d.get("residuals") or {}
    for kind in ("camera", "projector"):
        per_view = (res.get(kind) or {}).get("rms_per_view_px") if isinstance(res.get(kind), dict) else None
        if per_view:
            rms[kind] = [float(v) for v in per_view]
    files = {str(path): sha256(path)}
    views = []
    obs = path.with_name("observations.json")
    if obs.exists():
        files[str(obs)] = sha256(obs)
        for i, v in enumerate(json.loads(obs.read_text()).get("views", [])):
            pix = {k: np.asarray(v[k], dtype=np.float64) for k in ("camera", "projector") if k in v}
            views.append(ViewObservations(v.get("name", f"view {i + 1}"), np.asarray(v["board_points"], dtype=np.float64), pix))
    return CalibrationRecord(label, system, std, views, rms, files, "calibration.json")


def load_calibration_record(paths, label: str) -> CalibrationRecord:
    """Read one side of the report (see the module docstring)."""
    paths = [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]
    missing = [str(p) for p in paths if not p.exists()]
    if missing:
        raise ReportError(f"{label}: no such file(s) {missing}")
    if len(paths) == 2 and all(p.suffix.lower() == ".mat" for p in paths):
        return _from_bouguet(paths, label)
    if len(paths) == 1 and paths[0].suffix.lower() == ".json":
        return _from_json(paths[0], label)
    raise ReportError(f"{label}: give a calibration.json or a Bouguet .mat pair (camera, projector); "
                      f"got {[str(p) for p in paths]}")


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
