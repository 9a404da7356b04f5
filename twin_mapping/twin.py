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
import math
from pathlib import Path

from calib.system import SystemModel
from unwrap.safe_output import write_text

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
    bad = _non_finite(twin)
    if bad:
        raise TwinError(f"the twin of this calibration is not finite at {', '.join(bad[:4])} (camera fx = "
                        f"{system.camera.fx:g}, projector fx = {system.projector.fx:g} px): the calibration is "
                        "not a usable camera + projector model")
    return twin


def _non_finite(value, where: str = "") -> list[str]:
    """Key paths (``camera.location_mm[0] = inf``) of the non-finite numbers in a JSON-ready value."""
    if isinstance(value, dict):
        return [b for k, v in value.items() for b in _non_finite(v, f"{where}.{k}" if where else str(k))]
    if isinstance(value, (list, tuple)):
        return [b for i, v in enumerate(value) for b in _non_finite(v, f"{where}[{i}]")]
    if isinstance(value, float) and not math.isfinite(value):
        return [f"{where} = {value}"]
    return []


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
    bad = _non_finite(twin)
    if bad:   # JSON has no inf / NaN: json.dumps would write the invalid tokens Infinity / NaN
        raise TwinError(f"{path}: not written: non-finite value(s) {', '.join(bad[:4])}")
    write_text(path, json.dumps(twin, indent=2, allow_nan=False) + "\n")
    return path


def read_twin_json(path) -> dict:
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise TwinError(f"{path}: no such file") from None
    except json.JSONDecodeError as exc:
        raise TwinError(f"{path}: not valid JSON ({exc})") from None
