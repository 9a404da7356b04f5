"""A calibration with what backs it: its 1-sigma uncertainties, per-view residual RMS, the board
observations it was computed from, and the SHA-256 of its input files (what the twin-equivalence
report compares).

``load_calibration_record(paths, label)`` reads
- a Bouguet ``.mat`` pair (camera, projector): parameters of board pose 1 as world, the toolbox's
  3-sigma errors (divided by 3 here), per-view board points and pixels of both devices, and the
  per-view reprojection RMS;
- a ``calibration.json`` with the keys ``calib run`` writes (:mod:`calib.io.outputs`:
  ``uncertainties_1sigma``, ``residuals.views[i][device].rms_px``), with ``observations.json``
  beside it when present.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FormatError
from . import load_system
from ..observations import ViewObservations, read_observations_json
from ..system import SystemModel

INTRINSICS = ("fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3")
"""Parameters a record's uncertainties may name, per device."""


@dataclass
class CalibrationRecord:
    """One calibration and its backing.

    - label: its name in messages and reports; system: the SystemModel.
    - std: {device: {parameter: 1-sigma}} (may be empty).
    - views: [calib.observations.ViewObservations] board observations (may be empty).
    - residual_rms_px: {device: [RMS per view, px]} (may be empty).
    - files: {path: sha256}; kind: "bouguet" or "calibration.json".
    """

    label: str
    system: SystemModel
    std: dict
    views: list
    residual_rms_px: dict
    files: dict
    kind: str


def sha256(path) -> str:
    """Hex SHA-256 of a file (read in 1 MiB chunks)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _from_bouguet(paths, label) -> CalibrationRecord:
    from .bouguet import read_bouguet

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
            raise FormatError(f"{paths[0]} and {paths[1]}: view {i + 1} has different board points in the two files")
        views.append(ViewObservations(cam.points_board[i], {"camera": cam.points_px[i], "projector": prj.points_px[i]},
                                      name=f"pose {i + 1}"))
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
    per_view = (d.get("residuals") or {}).get("views") or []  # calib run: residuals.views[i][device].rms_px
    for kind in ("camera", "projector"):
        values = [v[kind]["rms_px"] for v in per_view if isinstance(v.get(kind), dict) and "rms_px" in v[kind]]
        if values:
            rms[kind] = [float(x) for x in values]
    files = {str(path): sha256(path)}
    views = []
    obs = path.with_name("observations.json")
    if obs.exists():
        files[str(obs)] = sha256(obs)
        views = read_observations_json(obs).views
    return CalibrationRecord(label, system, std, views, rms, files, "calibration.json")


def load_calibration_record(paths, label: str) -> CalibrationRecord:
    """Read a calibration with its uncertainties and observations (see the module docstring);
    ``label`` names it in messages and reports."""
    paths = [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]
    missing = [str(p) for p in paths if not p.exists()]
    if missing:
        raise FormatError(f"{label}: no such file(s) {missing}")
    if len(paths) == 2 and all(p.suffix.lower() == ".mat" for p in paths):
        return _from_bouguet(paths, label)
    if len(paths) == 1 and paths[0].suffix.lower() == ".json":
        return _from_json(paths[0], label)
    raise FormatError(f"{label}: give a calibration.json or a Bouguet .mat pair (camera, projector); "
                      f"got {[str(p) for p in paths]}")
