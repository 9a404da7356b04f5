"""Pick the reader of a calibration from its file name(s)."""
from __future__ import annotations

from pathlib import Path

from ..errors import FormatError
from ..system import SystemModel, check_rig, default_system


def load_system(paths=(), *, repair_rotation: bool = False, camera_size=None,
                projector_size=None) -> SystemModel:
    """Load a camera + projector system.

    ARGUMENTS
    - paths: nothing (the built-in default system), one ``calibration.json``, one OpenCV
      FileStorage ``.xml``/``.yml``/``.yaml``, two ``.cameramodel`` files (camera, projector) or two
      Bouguet ``.mat`` files (camera, projector; board pose 1 as world).

    A rig that cannot be a structured-light system is refused (:func:`calib.system.check_rig`:
    camera and projector at one place, or a pair of files given projector first).
    """
    system = _read_system(paths, repair_rotation=repair_rotation, camera_size=camera_size,
                          projector_size=projector_size)
    if isinstance(paths, (str, Path)):
        paths = [paths]
    check_rig(system, " ".join(str(p) for p in paths) or "the built-in system")
    return system


def _read_system(paths, *, repair_rotation: bool = False, camera_size=None,
                 projector_size=None) -> SystemModel:
    """The reader :func:`load_system` picks from the file name(s)."""
    from .bouguet import read_bouguet_pair
    from .calibration_json import read_calibration_json
    from .mrcal_model import read_cameramodel
    from .opencv_storage import read_opencv_storage

    if isinstance(paths, (str, Path)):
        paths = [paths]
    paths = [Path(p) for p in paths]
    if not paths:
        return default_system()
    suffixes = [p.suffix.lower() for p in paths]
    if len(paths) == 1 and suffixes[0] == ".json":
        return read_calibration_json(paths[0], repair_rotation=repair_rotation)
    if len(paths) == 1 and suffixes[0] in (".xml", ".yml", ".yaml"):
        return read_opencv_storage(paths[0], camera_size=camera_size, projector_size=projector_size,
                                   repair_rotation=repair_rotation)
    if len(paths) == 2 and suffixes == [".cameramodel"] * 2:
        from ..system import SystemModel as _S
        return _S(read_cameramodel(paths[0], kind="camera", repair_rotation=repair_rotation),
                  read_cameramodel(paths[1], kind="projector", repair_rotation=repair_rotation),
                  {"source": {"format": "mrcal cameramodel", "camera": str(paths[0]),
                              "projector": str(paths[1])}})
    if len(paths) == 2 and suffixes == [".mat"] * 2:
        return read_bouguet_pair(paths[0], paths[1], repair_rotation=repair_rotation)
    raise FormatError(
        f"cannot tell the format of {[str(p) for p in paths]}: give one calibration.json, one OpenCV "
        ".xml/.yml, two .cameramodel files (camera, projector) or two Bouguet .mat files (camera, projector)")


def save_system(system: SystemModel, paths, *, skew_tol_px: float | None = None) -> list[Path]:
    """Write a system in the format its path(s) name (the writers beside :func:`load_system`'s
    readers): one ``.json`` (calibration.json), one OpenCV ``.yml``/``.yaml``/``.xml`` (SLStudio key
    set, world = camera frame), or two ``.cameramodel`` files (camera, projector; mrcal refuses a
    skew it cannot hold beyond ``skew_tol_px``). Returns the paths written."""
    from .calibration_json import write_calibration_json
    from .mrcal_model import write_cameramodel
    from .opencv_storage import write_opencv_storage

    if isinstance(paths, (str, Path)):
        paths = [paths]
    paths = [Path(p) for p in paths]
    suffixes = [p.suffix.lower() for p in paths]
    if len(paths) == 1 and suffixes[0] == ".json":
        return [write_calibration_json(system, paths[0])]
    if len(paths) == 1 and suffixes[0] in (".xml", ".yml", ".yaml"):
        return [write_opencv_storage(system, paths[0])]
    if len(paths) == 2 and suffixes == [".cameramodel"] * 2:
        for device, path in zip((system.camera, system.projector), paths):
            write_cameramodel(device, path, **({} if skew_tol_px is None else {"skew_tol_px": skew_tol_px}))
        return paths
    raise FormatError(f"cannot tell the output format of {[str(p) for p in paths]}: give one .json, one OpenCV "
                      ".yml/.xml, or two .cameramodel files (camera, projector)")
