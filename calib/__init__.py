"""sltwin calib: camera/projector models, calibration files, and (later stages) calibration.

Public surface:

- ``DeviceModel``, ``SystemModel``, ``default_system``: device and system models.
- ``load_system``: read any supported calibration file(s).
- ``CalibError``, ``ModelError``, ``FormatError``: errors.
"""
from .device import DeviceModel  # noqa: F401
from .errors import CalibError, FormatError, ModelError  # noqa: F401
from .io import load_system  # noqa: F401
from .system import SystemModel, default_system  # noqa: F401
