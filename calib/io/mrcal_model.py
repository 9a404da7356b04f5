"""mrcal ``.cameramodel`` files: read through mrcal itself, written in mrcal's text format without
importing mrcal (:func:`cameramodel_text`: the bytes ``mrcal.cameramodel.write`` writes for a model
without a valid-intrinsics region or optimisation inputs, a test; mrcal's import costs ``calib run``
0.25-0.7 s).

mrcal's OpenCV lens models hold (fx, fy, cx, cy) and 4/5/8/12 distortion terms, no skew. Writing a
device with skew is refused unless the skew's effect is below ``skew_tol_px`` at every image
corner (default 0.01 px), in which case it is dropped and the drop is returned in the report.
mrcal's text format keeps 10 significant digits. Extrinsics: mrcal's ``rt_cam_ref`` maps reference (our world) to the device, as our R, t do.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from unwrap.safe_output import write_text

from ..device import DeviceModel
from ..errors import FormatError
from ..rotation import matrix_from_rotvec, rotvec_from_matrix

#: Default largest tolerated effect, in pixels at the image corners, of dropping skew.
SKEW_TOL_PX = 0.01

_LENSMODELS = {0: "LENSMODEL_PINHOLE", 4: "LENSMODEL_OPENCV4", 5: "LENSMODEL_OPENCV5",
               8: "LENSMODEL_OPENCV8", 12: "LENSMODEL_OPENCV12"}


def skew_effect_px(device: DeviceModel) -> float:
    """Largest pixel shift at the image corners caused by the skew term ``s * yd``."""
    corners = device.image_corners()
    yd = (corners[:, 1] - device.cy) / device.fy
    return float(np.max(np.abs(device.skew * yd)))


def to_cameramodel(device: DeviceModel, *, skew_tol_px: float = SKEW_TOL_PX):
    """A ``mrcal.cameramodel`` of the device, and a list of report lines (what was dropped)."""
    import mrcal

    report = _skew_report(device, skew_tol_px)
    intrinsics = np.concatenate([[device.fx, device.fy, device.cx, device.cy], device.distortion])
    rt = np.concatenate([rotvec_from_matrix(device.R), device.t])
    model = mrcal.cameramodel(intrinsics=(_LENSMODELS[device.distortion.size], intrinsics),
                              imagersize=np.array(device.size, dtype=np.int32),
                              extrinsics_rt_fromref=rt)
    return model, report


def _skew_report(device: DeviceModel, skew_tol_px: float) -> list[str]:
    """What dropping the device's skew costs (report lines); refused beyond ``skew_tol_px``."""
    if device.skew == 0.0:
        return []
    effect = skew_effect_px(device)
    if effect > skew_tol_px:
        raise FormatError(
            f"{device.name or device.kind}: skew s = {device.skew:.6g} px cannot be held by mrcal's "
            f"lens models; dropping it would move image corners by {effect:.4f} px, more than the "
            f"tolerance {skew_tol_px:g} px. Calibrate with skew fixed at 0, or raise the tolerance "
            "(--skew-tol) to accept the loss")
    return [f"{device.name or device.kind}: skew {device.skew:.6g} px dropped "
            f"(effect {effect:.4f} px at the image corners <= {skew_tol_px:g} px)"]


def cameramodel_text(device: DeviceModel, note: str, *, skew_tol_px: float = SKEW_TOL_PX) -> tuple[str, list[str]]:
    """(the ``.cameramodel`` text of the device, report lines), as ``mrcal.cameramodel.write``
    writes it (10 significant digits, mrcal's key order and comments)."""
    report = _skew_report(device, skew_tol_px)
    return _text(device, note), report


def _text(device: DeviceModel, note: str) -> str:
    """The ``.cameramodel`` text of :func:`cameramodel_text` (skew already checked by the caller)."""
    intrinsics = np.concatenate([[device.fx, device.fy, device.cx, device.cy], device.distortion])
    rt = np.concatenate([rotvec_from_matrix(device.R), device.t])
    if not (np.all(np.isfinite(intrinsics)) and np.all(np.isfinite(rt))):
        raise FormatError(f"{device.name or device.kind}: non-finite intrinsics or pose: no camera model to write")
    lines = [f"# {line}" for line in note.splitlines()]
    lines += ["{", f"    'lensmodel':  '{_LENSMODELS[device.distortion.size]}',", "",
              "    # intrinsics are fx,fy,cx,cy,distortion0,distortion1,....",    # (the OpenCV and pinhole models')
              "    'intrinsics': [" + "".join(f" {v:.10g}," for v in intrinsics) + "],", "",
              "    # extrinsics are rt_fromref",
              "    'extrinsics': [" + "".join(f" {v:.10g}," for v in rt) + "],", "",
              "    'imagersize': [" + "".join(f" {int(v):d}," for v in device.size) + "],", "", "", "}"]
    return "\n".join(lines) + "\n"


def write_cameramodel(device: DeviceModel, path, *, skew_tol_px: float = SKEW_TOL_PX) -> list[str]:
    """Write the device as a mrcal ``.cameramodel`` (:func:`cameramodel_text`); return the report lines."""
    report = _skew_report(device, skew_tol_px)
    note = f"sltwin {device.kind}" + (f"; {'; '.join(report)}" if report else "")
    write_text(path, _text(device, note))     # atomic: a failed write leaves the previous file
    return report


def read_cameramodel(path, *, kind: str = "camera", repair_rotation: bool = False) -> DeviceModel:
    """Read a mrcal ``.cameramodel`` with an OpenCV or pinhole lens model."""
    import mrcal

    path = Path(path)
    if not path.exists():
        raise FormatError(f"{path}: no such file")
    try:
        model = mrcal.cameramodel(str(path))
    except Exception as exc:
        raise FormatError(f"{path}: mrcal cannot read it ({exc})") from None
    lensmodel, intrinsics = model.intrinsics()
    inverse = {v: k for k, v in _LENSMODELS.items()}
    if lensmodel not in inverse:
        raise FormatError(f"{path}: lens model {lensmodel} has no OpenCV equivalent; supported: "
                          f"{sorted(inverse)}")
    fx, fy, cx, cy = intrinsics[:4]
    rt = model.extrinsics_rt_fromref()
    return DeviceModel(size=tuple(int(v) for v in model.imagersize()),
                       K=[[fx, 0, cx], [0, fy, cy], [0, 0, 1]], distortion=intrinsics[4:],
                       R=matrix_from_rotvec(rt[:3]), t=rt[3:], kind=kind, name=kind,
                       repair_rotation=repair_rotation)
