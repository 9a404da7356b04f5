"""System-level twin: both devices, ``twin.json`` read/write, and the inverse to a SystemModel.

SYNOPSIS

    >>> from calib import default_system
    >>> from twin_mapping.twin import from_twin, to_twin
    >>> s = default_system()
    >>> twin = to_twin(s)
    >>> [round(v, 4) for v in twin["camera"]["location_mm"]]
    [109.1986, -93.2745, 835.7891]
    >>> abs(from_twin(twin).projector.fy - s.projector.fy) < 1e-9
    True
"""
from __future__ import annotations

import json
from pathlib import Path

from calib.system import SystemModel

from .datasheets import datasheets_for
from .errors import TwinError
from .mapping import device_to_twin, twin_to_device


def to_twin(system: SystemModel, datasheets: dict | None = None) -> dict:
    """The twin of a camera + projector system (the ``twin.json`` dictionary), lengths in mm."""
    sheets = datasheets or datasheets_for(system)
    twin = {"units": {"length": "mm", "angles": "deg"},
            "convention": "Blender: device-to-world rotation R^T diag(1,-1,-1), 'XYZ' Euler; "
                          "location -R^T t; sensor_fit HORIZONTAL",
            "camera": device_to_twin(system.camera, sheets["camera"]),
            "projector": device_to_twin(system.projector, sheets["projector"])}
    if system.repairs:
        twin["repairs"] = list(system.repairs)
    return twin


def from_twin(twin: dict) -> SystemModel:
    """Inverse of ``to_twin``."""
    missing = [k for k in ("camera", "projector") if k not in twin]
    if missing:
        raise TwinError(f"twin: missing {missing}")
    return SystemModel(twin_to_device(twin["camera"], kind="camera"),
                       twin_to_device(twin["projector"], kind="projector"))


def write_twin_json(twin: dict, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(twin, indent=2) + "\n")
    return path


def read_twin_json(path) -> dict:
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise TwinError(f"{path}: no such file") from None
    except json.JSONDecodeError as exc:
        raise TwinError(f"{path}: not valid JSON ({exc})") from None
