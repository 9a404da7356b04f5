"""OpenCV FileStorage (XML / YAML) calibrations of camera + projector rigs.

Recognised key sets (world = camera frame, so the camera has R = I, t = 0):

- SLStudio ``calibration.xml``: Kc, kc, Kp, kp, Rp, Tp, frameWidth/Height, screenResX/Y;
  ``x_prj = Rp x_cam + Tp``.
- SLMaster ``caliInfo.yml``: M1, D1, S (camera size), M4, D4 (projector), Rlp, Tlp (camera ->
  projector). The projector size is not stored: pass ``projector_size``.
- ``cv2.stereoCalibrate`` style: cameraMatrix1/2 (or M1/M2), distCoeffs1/2 (D1/D2), R, T,
  image sizes given by ``camera_size`` / ``projector_size`` when absent.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..device import DeviceModel
from ..errors import FormatError
from ..system import SystemModel

_LAYOUTS = {
    "slstudio": dict(Kc="Kc", dc="kc", Kp="Kp", dp="kp", R="Rp", T="Tp"),
    "slmaster": dict(Kc="M1", dc="D1", Kp="M4", dp="D4", R="Rlp", T="Tlp"),
    "stereo": dict(Kc="cameraMatrix1", dc="distCoeffs1", Kp="cameraMatrix2", dp="distCoeffs2", R="R", T="T"),
    "stereo_m": dict(Kc="M1", dc="D1", Kp="M2", dp="D2", R="R", T="T"),
}


def _read_nodes(path: Path) -> dict:
    import cv2

    if not path.exists():
        raise FormatError(f"{path}: no such file")
    if path.is_file() and path.stat().st_size == 0:
        raise FormatError(f"{path}: the file is empty (0 bytes), not an OpenCV FileStorage calibration")
    try:   # OpenCV raises SystemError / cv2.error for an empty or truncated file
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (SystemError, cv2.error) as exc:
        cause = str(exc.__cause__ or exc).strip().splitlines()[-1]
        raise FormatError(f"{path}: OpenCV cannot parse it as FileStorage XML/YAML (empty or truncated?): "
                          f"{cause}") from None
    if not fs.isOpened():
        raise FormatError(f"{path}: OpenCV cannot open it as FileStorage XML/YAML")
    out = {}
    try:
        root = fs.root()
        if not root.isMap():
            raise FormatError(f"{path}: holds a FileStorage {'sequence' if root.isSeq() else 'value'} (an image "
                              "list?), not a calibration's named matrices")
        for key in root.keys():
            node = fs.getNode(key)
            if node.isReal() or node.isInt():
                out[key] = float(node.real())
            elif node.isString():
                out[key] = node.string()
            elif node.isMap():   # an opencv-matrix; sequences (image lists) are not calibration data
                try:
                    mat = node.mat()
                except cv2.error:   # a nested map that is not a matrix
                    continue
                if mat is not None:
                    out[key] = np.asarray(mat, dtype=np.float64)
        if not out:
            raise FormatError(f"{path}: no numbers or matrices under the keys {list(root.keys())} (an image "
                              "list?): not a calibration")
    finally:
        fs.release()
    return out


def read_opencv_storage(path, *, camera_size=None, projector_size=None,
                        repair_rotation: bool = False) -> SystemModel:
    """Read a camera + projector rig from an OpenCV FileStorage file (layouts above)."""
    path = Path(path)
    nodes = _read_nodes(path)
    for name, keys in _LAYOUTS.items():
        if all(k in nodes for k in keys.values()):
            layout, k = name, keys
            break
    else:
        raise FormatError(f"{path}: no known calibration key set; found keys {sorted(nodes)}; "
                          f"expected one of {[sorted(v.values()) for v in _LAYOUTS.values()]}")
    if camera_size is None:
        if "frameWidth" in nodes:
            camera_size = (nodes["frameWidth"], nodes["frameHeight"])
        elif "S" in nodes:
            camera_size = tuple(nodes["S"].reshape(-1)[:2])
    if projector_size is None and "screenResX" in nodes:
        projector_size = (nodes["screenResX"], nodes["screenResY"])
    for what, size in (("camera", camera_size), ("projector", projector_size)):
        if size is None:
            raise FormatError(f"{path}: the {what} image size is not stored in this {layout} file; "
                              f"give it ({what}_size=(width, height), or --{what}-size W H)")
    cam = DeviceModel(size=tuple(int(v) for v in camera_size), K=nodes[k["Kc"]],
                      distortion=nodes[k["dc"]].reshape(-1), kind="camera", name="camera")
    # FileStorage often stores float32 ("dt: f"): re-orthonormalise only when asked
    prj = DeviceModel(size=tuple(int(v) for v in projector_size), K=nodes[k["Kp"]],
                      distortion=nodes[k["dp"]].reshape(-1), R=nodes[k["R"]], t=nodes[k["T"]].reshape(-1),
                      kind="projector", name="projector", repair_rotation=repair_rotation)
    meta = {"source": {"format": f"opencv-filestorage ({layout})", "path": str(path),
                       "world": "camera frame"}}
    for key in ("cam_error", "proj_error", "stereo_error"):
        if key in nodes:
            meta.setdefault("source_errors_px", {})[key] = nodes[key]
    return SystemModel(cam, prj, meta)


def write_opencv_storage(system: SystemModel, path) -> Path:
    """Write a camera + projector system as an OpenCV FileStorage file (``.yml``/``.yaml`` or ``.xml``
    by the suffix), in the SLStudio key set, which holds everything and which
    :func:`read_opencv_storage` (and SLStudio) read back: Kc, kc, Kp, kp, Rp, Tp (camera ->
    projector, ``x_prj = Rp x_cam + Tp``, mm), frameWidth/Height, screenResX/Y. The world becomes
    the camera frame, as in every OpenCV rig; skew stays in K and distortion keeps its length.
    Values are float64 (FileStorage writes 16 significant digits)."""
    import cv2

    path = Path(path)
    if path.suffix.lower() not in (".yml", ".yaml", ".xml"):
        raise FormatError(f"{path}: an OpenCV FileStorage file ends in .yml, .yaml or .xml")
    cam, prj = system.camera, system.projector
    R = prj.R @ cam.R.T
    t = prj.t - R @ cam.t
    path.parent.mkdir(parents=True, exist_ok=True)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    if not fs.isOpened():
        raise FormatError(f"{path}: OpenCV cannot open it for writing")
    try:
        for key, value in (("Kc", cam.K), ("kc", cam.distortion.reshape(-1, 1)), ("Kp", prj.K),
                           ("kp", prj.distortion.reshape(-1, 1)), ("Rp", R), ("Tp", t.reshape(3, 1))):
            if value.size:
                fs.write(key, np.ascontiguousarray(value, dtype=np.float64))
            else:   # no distortion: OpenCV cannot store an empty matrix, so one row of zeros
                fs.write(key, np.zeros((4, 1)))
        for key, value in (("frameWidth", cam.width), ("frameHeight", cam.height),
                           ("screenResX", prj.width), ("screenResY", prj.height)):
            fs.write(key, int(value))
    finally:
        fs.release()
    return path
