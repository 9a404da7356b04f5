"""sltwin calib: camera/projector models and their files, boards and their detection, calibration
from board captures or point observations, triangulation.

Public surface:

- models: ``DeviceModel``, ``SystemModel``, ``default_system`` (the paper's real system),
  ``load_system`` (any supported calibration file or pair) and ``save_system`` (calibration.json,
  OpenCV YAML/XML or a mrcal pair, by the file name).
- boards: ``Board``, ``paper_board``; detection ``detect_board``.
- observations: ``Observations``, ``ViewObservations``, ``observations_from_captures`` (board
  captures -> camera and projector pixels).
- calibration: ``run_calibration`` -> ``Calibration`` (Zhang seeds + bundle adjustment, settings
  ``BAConfig`` / ``DeviceConfig``; ``reweight_views`` gives noisy views their own noise level);
  ``calibrate_captures`` and ``calibrate_observations`` (calibrate and write every output, as
  ``calib run``); ``assess_uncertainty`` (the reported uncertainty: per-pose error model,
  resampling over poses, residual diagnostics).
- 3D: ``triangulate`` (distortion-aware), ``triangulate_linear`` (the paper's),
  ``triangulate_both`` (both projector coordinates), ``coordinate_conditioning`` (which
  coordinate a rig triangulates well), ``points_from_phase``, ``sphere_from_phase``, ``fit_sphere``.
- errors (calib.errors, all ValueError): ``CalibError`` and ``ModelError``,
  ``FormatError``, ``BoardError``, ``DetectionError``, ``MarkerPhaseError``, ``CaptureError``,
  ``ObservationError``, ``InitError``, ``BundleAdjustmentError``, ``TriangulationError``,
  ``OutputError``, ``UncertaintyError``.

Progress goes to the `calib` logger.
"""
import sys

# ``triangulate`` names both a submodule and its function: the module is loaded at once (numpy only),
# so that the package attribute stays the function, as it always was.
from .triangulate import (fit_sphere, points_from_phase, sphere_from_phase, triangulate, triangulate_both,
                          triangulate_linear)

# The other public names, by submodule. PEP 562: a name's submodule is imported at its first use, so
# ``import calib.pipeline`` (an observation-only ``calib run``) loads neither the board detection
# (cv2, scipy.spatial, scipy.ndimage) nor the capture pipeline (unwrapping) it does not use.
_HOME = {
    "board": ("Board", "paper_board"),
    "adjustment.problem": ("BAConfig", "DeviceConfig"),
    "calibrate": ("Calibration", "reweight_views", "run_calibration"),
    "coordinate_choice": ("coordinate_conditioning",),
    "detect.captures": ("observations_from_captures",),
    "detect": ("detect_board",),
    "device": ("DeviceModel",),
    "errors": ("BoardError", "BundleAdjustmentError", "CalibError", "CaptureError", "DetectionError", "FormatError",
               "InitError", "MarkerPhaseError", "ModelError", "ObservationError", "OutputError", "TriangulationError",
               "UncertaintyError"),
    "io": ("load_system", "save_system"),
    "observations": ("Observations", "ViewObservations"),
    "pipeline": ("calibrate_captures", "calibrate_observations"),
    "system": ("SystemModel", "default_system"),
    "uncertainty.assess": ("assess_uncertainty",),
}


def __getattr__(name):
    """The public name ``name``, imported from its submodule at first use (PEP 562)."""
    home = next((m for m, names in _HOME.items() if name in names), None)
    if home is None:
        raise AttributeError(f"module 'calib' has no attribute {name!r}")
    if home == "board":
        from . import board as module
    elif home == "adjustment.problem":
        from .adjustment import problem as module
    elif home == "calibrate":
        from . import calibrate as module
    elif home == "coordinate_choice":
        from . import coordinate_choice as module
    elif home == "detect.captures":
        from .detect import captures as module
    elif home == "detect":
        from . import detect as module
    elif home == "device":
        from . import device as module
    elif home == "errors":
        from . import errors as module
    elif home == "io":
        from . import io as module
    elif home == "observations":
        from . import observations as module
    elif home == "pipeline":
        from . import pipeline as module
    elif home == "system":
        from . import system as module
    else:
        from .uncertainty import assess as module
    value = getattr(module, name)
    setattr(sys.modules[__name__], name, value)
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))


__all__ = [
    "DeviceModel", "SystemModel", "default_system", "load_system", "save_system",
    "Board", "paper_board", "detect_board",
    "Observations", "ViewObservations", "observations_from_captures",
    "run_calibration", "reweight_views", "Calibration", "BAConfig", "DeviceConfig", "calibrate_captures",
    "calibrate_observations", "assess_uncertainty",
    "triangulate", "triangulate_linear", "triangulate_both", "coordinate_conditioning", "points_from_phase",
    "sphere_from_phase", "fit_sphere",
    "CalibError", "ModelError", "FormatError", "BoardError", "DetectionError", "MarkerPhaseError", "CaptureError",
    "ObservationError", "InitError", "BundleAdjustmentError", "TriangulationError", "OutputError",
    "UncertaintyError",
]
