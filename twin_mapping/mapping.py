"""Calibration <-> digital-twin (Blender) parameters, per device, and back.

Forward (``device_to_twin``), for a device with ``x_dev = R X_world + t`` (mm) and intrinsics K:

- device-to-world rotation in Blender's camera convention (looks down -Z, +Y up):
  ``M = R^T @ diag(1, -1, -1)``; ``rotation_euler_deg`` = Blender 'XYZ' Euler angles of M;
- ``location_mm = -R^T t`` (the optical centre);
- Blender camera with ``sensor_fit = HORIZONTAL``: ``sensor_width_mm = W * pitch_x``,
  ``focal_length_mm = fx * pitch_x``; ``focal_length_y_mm = fy * pitch_y`` (reported; Blender
  holds one focal length and expresses fy through the pixel aspect);
- ``pixel_aspect = (fy/fx, 1)`` if fy >= fx else ``(1, fx/fy)`` (Blender needs both >= 1);
- lens shift, from Blender's view plane (pixel centres at integer coordinates, OpenCV rows top-down):
  ``shift_x = ((W-1)/2 - cx) / W``, ``shift_y = (cy - (H-1)/2) / W * fx/fy``;
- a projector also as a textured spot light: cone ``spot_size_deg`` that holds the image corners,
  and ``spot_scale_y`` = vertical/horizontal frustum extent (the ellipse the paper's twin uses);
- what Blender cannot represent (skew, distortion) goes in ``not_representable`` with its exact
  values and its largest effect in pixels at the image corners.

Inverse (``twin_to_device``) restores K, R, t (and skew/distortion from ``not_representable``).
Forward then inverse returns the input to rounding (tested to 1e-9).
"""
from __future__ import annotations

import math

import numpy as np

from calib.device import DeviceModel
from calib.distortion import undistort

from .datasheets import Datasheet
from .errors import TwinError
from .euler import euler_xyz_from_matrix, matrix_from_euler_xyz

FLIP_YZ = np.diag([1.0, -1.0, -1.0])


def skew_effect_px(device: DeviceModel) -> float:
    """Largest shift (px) at the image corners caused by the skew term."""
    yd = (device.image_corners()[:, 1] - device.cy) / device.fy
    return float(np.max(np.abs(device.skew * yd)))


def distortion_effect_px(device: DeviceModel) -> float:
    """Largest distance (px) at the image corners between the distorted and the ideal pinhole pixel.

    Each corner pixel is undistorted and re-projected without distortion; raises TwinError when
    the lens model is not invertible at a corner.
    """
    if not np.any(device.distortion):
        return 0.0
    corners = device.image_corners()
    xy, ok = undistort(device.pixels_to_normalized(corners), device.distortion)
    if not ok.all():
        raise TwinError(f"{device.name or device.kind}: the distortion model cannot be inverted at image "
                        f"corners {corners[~ok].tolist()}; its effect there is undefined")
    ideal = device.normalized_to_pixels(xy)
    with np.errstate(over="ignore", invalid="ignore"):   # an absurd model gives inf: to_twin refuses it
        return float(np.max(np.linalg.norm(ideal - corners, axis=1)))


def _frustum_tangents(device: DeviceModel) -> np.ndarray:
    """tan of the angles to the image edges of the ideal pinhole: (left, right, top, bottom) >= 0."""
    w, h = device.size
    return np.array([(device.cx + 0.5) / device.fx, (w - 0.5 - device.cx) / device.fx,
                     (device.cy + 0.5) / device.fy, (h - 0.5 - device.cy) / device.fy])


def device_to_twin(device: DeviceModel, datasheet: Datasheet) -> dict:
    """Twin parameters of one device (a JSON-ready dict; see the module docstring)."""
    label = device.name or device.kind
    datasheet.check(device.size, label)
    w, h = device.size
    px, py = datasheet.pixel_pitch_um
    M = device.R.T @ FLIP_YZ
    angles, lock = euler_xyz_from_matrix(M)
    fx, fy = device.fx, device.fy
    aspect = (fy / fx, 1.0) if fy >= fx else (1.0, fx / fy)
    twin = {
        "kind": device.kind,
        "rotation_euler_deg": np.degrees(angles).tolist(),
        "rotation_mode": "XYZ",
        "location_mm": device.center_world.tolist(),
        "focal_length_mm": fx * px / 1000.0,
        "focal_length_y_mm": fy * py / 1000.0,
        "sensor_size_mm": [w * px / 1000.0, h * py / 1000.0],
        "sensor_fit": "HORIZONTAL",
        "pixel_pitch_um": [px, py],
        "shift": [((w - 1) / 2.0 - device.cx) / w, (device.cy - (h - 1) / 2.0) / w * fx / fy],
        "resolution": [w, h],
        "pixel_aspect": list(aspect),
        "datasheet": datasheet.model,
        "not_representable": {
            "skew_px": device.skew,
            "skew_effect_px": skew_effect_px(device),
            "distortion": device.distortion.tolist(),
            "distortion_effect_px": distortion_effect_px(device),
        },
    }
    if lock:
        twin["gimbal_lock"] = ("second Euler angle at +-90 deg: the X and Z rotations share an axis; "
                               "Z set to 0 and X carries the rotation about it")
    if device.kind == "projector":
        tl, tr, tt, tb = _frustum_tangents(device)
        corner_tan = max(math.hypot(a, b) for a in (tl, tr) for b in (tt, tb))
        twin["spot"] = {
            "spot_size_deg": math.degrees(2.0 * math.atan(corner_tan)),
            "spot_scale_y": max(tt, tb) / max(tl, tr),
            "spot_blend": 0.0,
            "shadow_soft_size": 0.0,
        }
    return twin


_REQUIRED = ("rotation_euler_deg", "location_mm", "focal_length_mm", "sensor_size_mm", "shift",
             "resolution", "pixel_aspect")


def twin_to_device(twin: dict, *, kind: str | None = None) -> DeviceModel:
    """Inverse mapping: twin parameters -> DeviceModel (K, R, t; skew and distortion restored from
    ``not_representable`` when present)."""
    kind = kind or twin.get("kind", "camera")
    missing = [k for k in _REQUIRED if k not in twin]
    if missing:
        raise TwinError(f"{kind} twin: missing key(s) {missing}")
    if twin.get("sensor_fit", "HORIZONTAL") != "HORIZONTAL":
        raise TwinError(f"{kind} twin: sensor_fit {twin['sensor_fit']!r}; only HORIZONTAL is mapped")
    w, h = (int(v) for v in twin["resolution"])
    ax, ay = (float(v) for v in twin["pixel_aspect"])
    lens = float(twin["focal_length_mm"])
    sensor_w = float(twin["sensor_size_mm"][0])
    values = [lens, sensor_w, ax, ay, *twin["shift"], *twin["rotation_euler_deg"], *twin["location_mm"]]
    if not np.all(np.isfinite(values)):
        raise TwinError(f"{kind} twin: non-finite values {values}")
    if lens <= 0 or sensor_w <= 0 or ax <= 0 or ay <= 0:
        raise TwinError(f"{kind} twin: focal length, sensor width and pixel aspect must be > 0; "
                        f"got lens={lens}, sensor width={sensor_w}, aspect=({ax}, {ay})")
    fx = lens / sensor_w * w
    fy = fx * ax / ay
    sx, sy = (float(v) for v in twin["shift"])
    cx = (w - 1) / 2.0 - sx * w
    cy = (h - 1) / 2.0 + sy * w * fy / fx
    nr = twin.get("not_representable", {})
    skew = float(nr.get("skew_px", 0.0))
    M = matrix_from_euler_xyz(np.radians(twin["rotation_euler_deg"]))
    R = (M @ FLIP_YZ).T
    t = -R @ np.asarray(twin["location_mm"], dtype=np.float64)
    return DeviceModel(size=(w, h), K=[[fx, skew, cx], [0, fy, cy], [0, 0, 1]],
                       distortion=nr.get("distortion", []), R=R, t=t, kind=kind, name=kind)
