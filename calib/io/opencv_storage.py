"""OpenCV FileStorage (XML / YAML) calibrations of camera + projector rigs, from other tools.

Each tool names the same six quantities its own way; a file is read when one key set below is
complete (world = camera frame, so the camera has R = I, t = 0, and ``x_prj = R x_cam + T``):

| layout | camera K, dist | projector K, dist | R, T | image sizes |
|---|---|---|---|---|
| ``slstudio`` (SLStudio ``calibration.xml``) | Kc, kc | Kp, kp | Rp, Tp | frameWidth/Height, screenResX/Y |
| ``slmaster`` (SLMaster ``caliInfo.yml``) | M1, D1 | M4, D4 | Rlp, Tlp | S (camera) |
| ``procam`` (kamino410/procam-calibration ``calibration_result.xml``) | cam_int, cam_dist | proj_int, proj_dist | rotation (also its typo ``roration``), translation | img_shape (camera, rows x cols) |
| ``stereo`` (``cv2.stereoCalibrate`` style) | cameraMatrix1, distCoeffs1 | cameraMatrix2, distCoeffs2 | R, T | |
| ``stereo_m`` | M1, D1 | M2, D2 | R, T | |

Image sizes: ``frameWidth``/``frameHeight``, ``screenResX``/``screenResY``, ``S`` and
``projector_size``/``camera_size`` keys are (width, height); ``img_shape``/``image_shape`` are
numpy shapes, (rows, cols); ``imageSize``/``image_size`` are written both ways in the wild (a
``cv::Size`` is (width, height), a numpy shape (rows, cols)), so the order that puts the camera's
principal point nearer the image centre is taken, and the choice is recorded. A size the file
does not store is given by ``camera_size`` / ``projector_size`` (the refusal says so).

The keys used are recorded in ``system.meta["source"]["keys"]`` (and logged at INFO on the
``calib`` logger), so a user can see which entry became which quantity.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from unwrap.safe_output import atomic_path

from ..device import DeviceModel
from ..errors import FormatError
from ..system import SystemModel

log = logging.getLogger(__name__)

#: role -> accepted keys, per layout (the first key present is used)
_LAYOUTS = {
    "slstudio": dict(Kc=("Kc",), dc=("kc",), Kp=("Kp",), dp=("kp",), R=("Rp",), T=("Tp",)),
    "slmaster": dict(Kc=("M1",), dc=("D1",), Kp=("M4",), dp=("D4",), R=("Rlp",), T=("Tlp",)),
    "procam": dict(Kc=("cam_int",), dc=("cam_dist",), Kp=("proj_int",), dp=("proj_dist",),
                   R=("rotation", "roration"), T=("translation",)),
    "stereo": dict(Kc=("cameraMatrix1",), dc=("distCoeffs1",), Kp=("cameraMatrix2",), dp=("distCoeffs2",),
                   R=("R",), T=("T",)),
    "stereo_m": dict(Kc=("M1",), dc=("D1",), Kp=("M2",), dp=("D2",), R=("R",), T=("T",)),
}
#: (width key, height key) pairs and single (width, height) vectors, per device
_SIZE_PAIRS = {"camera": (("frameWidth", "frameHeight"), ("camera_width", "camera_height")),
               "projector": (("screenResX", "screenResY"), ("projector_width", "projector_height"),
                             ("proj_width", "proj_height"))}
_SIZE_WH = {"camera": ("S", "camera_size", "cam_size"), "projector": ("projector_size", "proj_size")}
_SIZE_ROWS_COLS = ("img_shape", "image_shape")
_SIZE_EITHER = ("imageSize", "image_size")


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


def _match_layout(nodes: dict, path: Path) -> tuple:
    """(layout name, {role: key used}) of the first complete key set of ``_LAYOUTS``."""
    for name, roles in _LAYOUTS.items():
        used = {role: next((k for k in keys if k in nodes), None) for role, keys in roles.items()}
        if all(used.values()):
            return name, used
    sets = {name: [" | ".join(keys) for keys in roles.values()] for name, roles in _LAYOUTS.items()}
    raise FormatError(f"{path}: no known calibration key set; found keys {sorted(nodes)}; expected one of "
                      + "; ".join(f"{n}: {', '.join(v)}" for n, v in sets.items()))


def _size_vector(value, key, path):
    v = np.asarray(value, dtype=np.float64).reshape(-1)
    if v.size < 2 or not np.all(np.isfinite(v[:2])) or np.any(v[:2] <= 0):
        raise FormatError(f"{path}: {key} = {v.tolist()} is not an image size (two positive numbers)")
    return float(v[0]), float(v[1])


def _centre_misfit(K, wh):
    """How far the principal point of ``K`` lies from the centre of a (W, H) image, in image units."""
    W, H = wh
    return abs(K[0, 2] - (W - 1) / 2) / W + abs(K[1, 2] - (H - 1) / 2) / H


def _stored_size(nodes: dict, device: str, K, path: Path):
    """((W, H), key or description) of the device's image size as stored, or (None, None)."""
    for wk, hk in _SIZE_PAIRS[device]:
        if wk in nodes and hk in nodes:
            return _size_vector([nodes[wk], nodes[hk]], f"{wk}/{hk}", path), f"{wk}/{hk} (width, height)"
    for key in _SIZE_WH[device]:
        if key in nodes:
            return _size_vector(nodes[key], key, path), f"{key} (width, height)"
    if device != "camera":
        return None, None
    for key in _SIZE_ROWS_COLS:
        if key in nodes:
            rows, cols = _size_vector(nodes[key], key, path)
            return (cols, rows), f"{key} (rows, cols)"
    for key in _SIZE_EITHER:
        if key in nodes:
            a, b = _size_vector(nodes[key], key, path)
            if _centre_misfit(K, (b, a)) < _centre_misfit(K, (a, b)):
                return (b, a), f"{key} read as (rows, cols): the principal point lies nearer that image's centre"
            return (a, b), f"{key} read as (width, height): the principal point lies nearer that image's centre"
    return None, None


def read_opencv_storage(path, *, camera_size=None, projector_size=None,
                        repair_rotation: bool = False) -> SystemModel:
    """Read a camera + projector rig from an OpenCV FileStorage file (layouts in the module docstring).

    ``camera_size`` / ``projector_size`` (W, H) override what the file stores. The keys used are in
    ``meta["source"]["keys"]``. Raises FormatError naming the keys found and the sets expected.
    """
    path = Path(path)
    nodes = _read_nodes(path)
    layout, used = _match_layout(nodes, path)
    for role, key in used.items():
        if not isinstance(nodes[key], np.ndarray):
            raise FormatError(f"{path}: {key} is a scalar or string, expected a matrix ({role})")
        if role in ("Kc", "Kp", "R") and nodes[key].size != 9:
            raise FormatError(f"{path}: {key} has {nodes[key].size} entries, a 3 x 3 matrix has 9")
    K_cam = nodes[used["Kc"]].reshape(3, 3)
    sizes = {}
    for what, given in (("camera", camera_size), ("projector", projector_size)):
        if given is not None:
            sizes[what] = (tuple(given), "given by the caller")
            continue
        size, how = _stored_size(nodes, what, K_cam, path)
        if size is None:
            raise FormatError(f"{path}: the {what} image size is not stored in this {layout} file; "
                              f"give it ({what}_size=(width, height), or --{what}-size W H)")
        sizes[what] = (size, how)
    cam = DeviceModel(size=tuple(int(v) for v in sizes["camera"][0]), K=nodes[used["Kc"]],
                      distortion=nodes[used["dc"]].reshape(-1), kind="camera", name="camera")
    # FileStorage often stores float32 ("dt: f"): re-orthonormalise only when asked
    prj = DeviceModel(size=tuple(int(v) for v in sizes["projector"][0]), K=nodes[used["Kp"]],
                      distortion=nodes[used["dp"]].reshape(-1), R=nodes[used["R"]],
                      t=nodes[used["T"]].reshape(-1), kind="projector", name="projector",
                      repair_rotation=repair_rotation)
    keys = {"camera_K": used["Kc"], "camera_distortion": used["dc"], "projector_K": used["Kp"],
            "projector_distortion": used["dp"], "R_prj_cam": used["R"], "t_prj_cam": used["T"],
            "camera_size": sizes["camera"][1], "projector_size": sizes["projector"][1]}
    log.info(f"{path.name}: {layout} layout; " + ", ".join(f"{k} <- {v}" for k, v in keys.items()))
    meta = {"source": {"format": f"opencv-filestorage ({layout})", "path": str(path),
                       "world": "camera frame", "keys": keys}}
    for key in ("cam_error", "proj_error", "stereo_error", "rms"):
        if key in nodes and isinstance(nodes[key], float):
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
    with atomic_path(path) as tmp:   # a failed write leaves the previous file
        _write_storage(cv2, tmp, path, cam, prj, R, t)
    return path


def _write_storage(cv2, tmp, path, cam, prj, R, t) -> None:
    fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
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
