"""Read and write ``calibration.json`` (DESIGN.md): both devices, world -> device poses, mm.

Extra keys (uncertainties, residuals, timings, meta) are kept in ``SystemModel.meta`` on read and
written back under their own names.
"""
from __future__ import annotations

import json
from pathlib import Path

from ..device import DeviceModel
from ..errors import FormatError
from ..system import SystemModel


def system_from_dict(d: dict, *, repair_rotation: bool = False, source: str = "calibration") -> SystemModel:
    """Build a SystemModel from the ``calibration.json`` dictionary."""
    if not isinstance(d, dict):
        raise FormatError(f"{source}: expected a JSON object, got {type(d).__name__}")
    units = d.get("units", "mm")
    if units != "mm":
        raise FormatError(f"{source}: units = {units!r}; only 'mm' is supported")
    missing = [k for k in ("camera", "projector") if k not in d]
    if missing:
        raise FormatError(f"{source}: missing key(s) {missing}; found {sorted(d)}")
    cam = DeviceModel.from_dict(d["camera"], kind="camera", name="camera", repair_rotation=repair_rotation)
    prj = DeviceModel.from_dict(d["projector"], kind="projector", name="projector",
                                repair_rotation=repair_rotation)
    meta = {k: v for k, v in d.items() if k not in ("camera", "projector", "units")}
    return SystemModel(cam, prj, meta)


def system_to_dict(system: SystemModel, **extra) -> dict:
    """The ``calibration.json`` dictionary of a system (plus ``extra`` top-level keys)."""
    d = {"units": "mm", "camera": system.camera.to_dict(), "projector": system.projector.to_dict()}
    d.update(system.meta)
    d.update(extra)
    return d


def read_calibration_json(path, *, repair_rotation: bool = False) -> SystemModel:
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise FormatError(f"{path}: no such file") from None
    except json.JSONDecodeError as exc:
        raise FormatError(f"{path}: not valid JSON ({exc})") from None
    return system_from_dict(d, repair_rotation=repair_rotation, source=str(path))


def write_calibration_json(system: SystemModel, path, **extra) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(system_to_dict(system, **extra), indent=2) + "\n")
    return path
