"""Read and write ``calibration.json`` (DESIGN.md): both devices, world -> device poses, mm.

Extra keys (uncertainties, residuals, timings, meta) are kept in ``SystemModel.meta`` on read and
written back under their own names.
"""
from __future__ import annotations

import json
from pathlib import Path

from unwrap.safe_output import write_text

from ..errors import FormatError
from ..system import SystemModel


def system_from_dict(d: dict, *, repair_rotation: bool = False, source: str = "calibration") -> SystemModel:
    """Build a SystemModel from the ``calibration.json`` dictionary (:meth:`SystemModel.from_dict`)."""
    return SystemModel.from_dict(d, repair_rotation=repair_rotation, source=source)


def system_to_dict(system: SystemModel, **extra) -> dict:
    """The ``calibration.json`` dictionary of a system, plus ``extra`` keys (:meth:`SystemModel.to_dict`)."""
    return system.to_dict(**extra)


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
    write_text(path, json.dumps(system_to_dict(system, **extra), indent=2) + "\n")
    return path
