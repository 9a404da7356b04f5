"""Exception type of twin_mapping: ``TwinError``, its one error root (a ``ValueError``; also a
``calib.errors.CalibError``, as it always was, for callers that catch calib's errors)."""
from calib.errors import CalibError


class TwinError(CalibError):
    """A digital-twin parameter set is invalid or cannot be mapped, or Blender failed."""
