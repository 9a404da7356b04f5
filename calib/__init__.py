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
from .board import Board, paper_board
from .adjustment.problem import BAConfig, DeviceConfig
from .calibrate import Calibration, reweight_views, run_calibration
from .coordinate_choice import coordinate_conditioning
from .detect.captures import observations_from_captures
from .detect import detect_board
from .device import DeviceModel
from .errors import (BoardError, BundleAdjustmentError, CalibError, CaptureError, DetectionError, FormatError,
                     InitError, MarkerPhaseError, ModelError, ObservationError, OutputError, TriangulationError,
                     UncertaintyError)
from .io import load_system, save_system
from .observations import Observations, ViewObservations
from .pipeline import calibrate_captures, calibrate_observations
from .system import SystemModel, default_system
from .triangulate import (fit_sphere, points_from_phase, sphere_from_phase, triangulate, triangulate_both,
                          triangulate_linear)
from .uncertainty.assess import assess_uncertainty

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
