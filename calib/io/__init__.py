"""Readers and writers of calibration files.

- ``calibration_json``: our ``calibration.json`` (DESIGN.md schema).
- ``bouguet``: Bouguet-toolbox ``.mat`` results (camera + projector pair; board pose 1 as world).
- ``mrcal_model``: mrcal ``.cameramodel`` files, through mrcal itself.
- ``opencv_storage``: OpenCV FileStorage XML/YAML calibrations (SLStudio, SLMaster, stereoCalibrate).

``load_system`` picks the reader from the file names, ``save_system`` the writer.
"""
from .loader import load_system, save_system  # noqa: F401
