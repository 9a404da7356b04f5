"""Exception types of the calib package.

Every error names the input, the offending value and what was expected, so that a user can act
on the message alone.
"""


class CalibError(Exception):
    """Base class of every error raised by ``calib``."""


class ModelError(CalibError, ValueError):
    """A camera/projector model is invalid (rotation, intrinsics, distortion, size)."""


class FormatError(CalibError, ValueError):
    """A calibration file cannot be read or written in the requested format."""
