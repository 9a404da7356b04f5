"""Exception types of the calib package: one root, ``CalibError`` (a ``ValueError``), and one
subclass per kind of refusal. Every error names the input, the offending value and what was
expected, so that a user can act on the message alone.

- ``ModelError``: a camera/projector model is invalid (rotation, intrinsics, distortion, size).
- ``FormatError``: a calibration file cannot be read or written in the requested format.
- ``BoardError``: a board definition is invalid.
- ``DetectionError``: the board is not found in an image, or its orientation is ambiguous.
- ``MarkerPhaseError``: inputs of the projector-pixel phase fit are inconsistent.
- ``CaptureError``: a capture folder or its description cannot be used.
- ``ObservationError``: observations are missing, inconsistent or too few.
- ``InitError``: the views do not determine a starting point (Zhang seeds).
- ``BundleAdjustmentError``: the adjustment cannot be set up or did not converge to a usable estimate.
- ``TriangulationError``: inputs of triangulation or of the sphere fit are inconsistent.
- ``OutputError``: results could not be written.
- ``UncertaintyError``: an uncertainty beyond the adjustment's own cannot be computed.
"""


class CalibError(ValueError):
    """Base class of every error raised by ``calib``."""


class ModelError(CalibError):
    """A camera/projector model is invalid (rotation, intrinsics, distortion, size)."""


class FormatError(CalibError):
    """A calibration file cannot be read or written in the requested format."""


class BoardError(CalibError):
    """A board definition is invalid (sizes, markers, polarity)."""


class DetectionError(CalibError):
    """The board was not found, too few features were identified, or the orientation is ambiguous."""


class MarkerPhaseError(CalibError):
    """Inputs of the marker phase fit are inconsistent (shapes, sizes, non-finite centres)."""


class CaptureError(CalibError):
    """A capture folder or its description cannot be used (missing keys, frames, poses)."""


class ObservationError(CalibError):
    """Observations are missing, inconsistent or too few for a calibration."""


class InitError(CalibError):
    """The views do not determine a starting point (degenerate geometry, too few views)."""


class BundleAdjustmentError(CalibError):
    """The adjustment cannot be set up or did not produce a usable estimate."""


class TriangulationError(CalibError):
    """Inputs to triangulation are inconsistent (shapes, non-finite calibration)."""


class OutputError(CalibError):
    """Results could not be written (the folder is not writable, the disk is full)."""


class UncertaintyError(CalibError):
    """An uncertainty beyond the adjustment's own cannot be computed for this calibration (a model
    the error model does not rebuild, too few poses to resample)."""
