"""Camera and projector models: pinhole intrinsics with skew, OpenCV distortion, world pose.

A projector is an inverse camera with the same model (DESIGN.md). Conventions:

    x_dev = R @ X_world + t                       (R, t: world -> device, mm)
    (x, y) = (x_dev / z_dev, y_dev / z_dev)        normalised coordinates
    (xd, yd) = distort((x, y), distortion)         OpenCV order, 0/4/5/8/12 terms
    u = fx * xd + s * yd + cx,  v = fy * yd + cy   pixels, centres at integer coordinates

All arrays are float64. Functions broadcast over leading dimensions.

SYNOPSIS

    >>> import numpy as np
    >>> from calib.device import DeviceModel
    >>> cam = DeviceModel(size=(640, 480), K=[[2000, 0, 320], [0, 2000, 240], [0, 0, 1]])
    >>> cam.project(np.array([[0.0, 0.0, 1000.0]])).tolist()
    [[320.0, 240.0]]
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .distortion import check_coefficients, distort, undistort
from .errors import ModelError
from .rotation import validate_rotation

KINDS = ("camera", "projector")


def _refuse_text(value, name: str) -> None:
    """numpy reads the text "2592.2" as a number; a quoted value is an error in the file: refuse it."""
    if value is None or (isinstance(value, np.ndarray) and value.dtype.kind in "fiub"):
        return
    try:
        text = any(isinstance(v, (str, bytes)) for v in np.asarray(value, dtype=object).reshape(-1))
    except (TypeError, ValueError) as exc:   # ragged nesting
        raise ModelError(f"{name}: cannot be read as numbers ({exc})") from None
    if text:
        raise ModelError(f"{name}: holds text, not numbers: {value!r} (write numbers without quotes)")


def _finite_array(value, shape, name: str) -> np.ndarray:
    _refuse_text(value, name)
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ModelError(f"{name}: cannot be read as numbers ({exc})") from None
    if shape is not None and a.shape != shape:
        if a.size == int(np.prod(shape)):
            a = a.reshape(shape)
        else:
            raise ModelError(f"{name}: expected shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ModelError(f"{name}: non-finite values {a.tolist()}")
    return a


@dataclass(frozen=True, eq=False)
class DeviceModel:
    """One device (camera, or projector as an inverse camera).

    ARGUMENTS
    - size: (width, height) in pixels.
    - K: (3,3) intrinsic matrix ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``, pixels.
    - distortion: OpenCV coefficients, 0/4/5/8/12 terms.
    - R, t: world -> device rotation (3,3) and translation (3,) in mm. Default: identity, zero.
    - kind: "camera" or "projector"; name: free text.
    - repair_rotation: replace a rounded R by the nearest rotation (SVD) instead of refusing it;
      the repair is recorded in ``repairs``.

    Invalid input raises ModelError naming the defect and the numbers.
    """

    size: tuple
    K: np.ndarray
    distortion: np.ndarray = field(default_factory=lambda: np.zeros(0))
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    kind: str = "camera"
    name: str = ""
    repair_rotation: bool = False
    repairs: tuple = ()

    def __post_init__(self):
        label = self.name or self.kind
        if self.kind not in KINDS:
            raise ModelError(f"{label}: kind must be one of {KINDS}, got {self.kind!r}")
        _refuse_text(self.size, f"{label}.size")
        _refuse_text(self.distortion, f"{label}.distortion")
        try:
            w, h = (int(v) for v in self.size)
            ok = (w, h) == tuple(float(v) for v in self.size)
        except (TypeError, ValueError):
            raise ModelError(f"{label}.size: expected (width, height) in pixels, got {self.size!r}") from None
        if not ok or w <= 0 or h <= 0:
            raise ModelError(f"{label}.size: expected positive integer (width, height), got {self.size!r}")
        K = _finite_array(self.K, (3, 3), f"{label}.K")
        if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
            raise ModelError(f"{label}.K: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ModelError(f"{label}.K: focal lengths must be > 0, got fx = {K[0, 0]!r}, fy = {K[1, 1]!r}")
        dist = check_coefficients(self.distortion, f"{label}.distortion")
        report: list[str] = list(self.repairs)
        R = validate_rotation(self.R, f"{label}.R", repair=self.repair_rotation, report=report)
        t = _finite_array(self.t, (3,), f"{label}.t")
        for key, value in (("size", (w, h)), ("K", K), ("distortion", dist), ("R", R), ("t", t),
                           ("repairs", tuple(report))):
            object.__setattr__(self, key, value)
        for a in (self.K, self.distortion, self.R, self.t):
            a.setflags(write=False)

    # -- intrinsics -------------------------------------------------------------------------
    @property
    def width(self) -> int:
        return self.size[0]

    @property
    def height(self) -> int:
        return self.size[1]

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def skew(self) -> float:
        return float(self.K[0, 1])

    @property
    def center_world(self) -> np.ndarray:
        """Optical centre in world coordinates, ``-R^T t`` (3,), mm."""
        return -self.R.T @ self.t

    def with_(self, **changes) -> "DeviceModel":
        """A copy with some fields replaced (validated again)."""
        return replace(self, **changes)

    def without_skew(self) -> "DeviceModel":
        """A copy with skew K[0, 1] = 0 (the rest unchanged)."""
        K = np.array(self.K)
        K[0, 1] = 0.0
        return self.with_(K=K)

    def without_skew_and_distortion(self) -> "DeviceModel":
        return self.without_skew().with_(distortion=np.zeros(0))

    # -- geometry ---------------------------------------------------------------------------
    def world_to_device(self, points_world) -> np.ndarray:
        """(..., 3) world points (mm) -> (..., 3) device-frame points (mm)."""
        p = np.asarray(points_world, dtype=np.float64)
        return p @ self.R.T + self.t

    def project_device(self, points_dev) -> np.ndarray:
        """(..., 3) device-frame points -> (..., 2) pixels. Points with z <= 0 give NaN."""
        p = np.asarray(points_dev, dtype=np.float64)
        z = p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = p[..., :2] / np.where(z > 0, z, np.nan)[..., None]
        return self.normalized_to_pixels(distort(xy, self.distortion))

    def project(self, points_world) -> np.ndarray:
        """(..., 3) world points (mm) -> (..., 2) pixels. Points behind the device give NaN."""
        return self.project_device(self.world_to_device(points_world))

    def normalized_to_pixels(self, xyd) -> np.ndarray:
        """Distorted normalised coordinates (..., 2) -> pixels (..., 2)."""
        xyd = np.asarray(xyd, dtype=np.float64)
        u = self.fx * xyd[..., 0] + self.skew * xyd[..., 1] + self.cx
        v = self.fy * xyd[..., 1] + self.cy
        return np.stack([u, v], axis=-1)

    def pixels_to_normalized(self, q) -> np.ndarray:
        """Pixels (..., 2) -> distorted normalised coordinates (..., 2) (inverse of K)."""
        q = np.asarray(q, dtype=np.float64)
        yd = (q[..., 1] - self.cy) / self.fy
        xd = (q[..., 0] - self.cx - self.skew * yd) / self.fx
        return np.stack([xd, yd], axis=-1)

    def unproject(self, q) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (..., 2) -> rays ``(x, y, 1)`` in the device frame (..., 3), and a validity mask.

        The mask is False where distortion could not be inverted (outside the lens model's
        invertible region) or the input is not finite.
        """
        xy, ok = undistort(self.pixels_to_normalized(q), self.distortion)
        rays = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
        return rays, ok

    def rays_world(self, q) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixels (..., 2) -> (origin (3,), unit directions (..., 3) in world, validity mask)."""
        rays, ok = self.unproject(q)
        d = rays @ self.R  # R^T applied to row vectors
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        return self.center_world, d, ok

    def image_corners(self) -> np.ndarray:
        """Pixel coordinates (4,2) of the outer corners of the image (pixel edges)."""
        w, h = self.size
        return np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])

    # -- serialisation ----------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The ``calibration.json`` form of this device (DESIGN.md keys)."""
        return {"size": list(self.size), "K": self.K.tolist(), "distortion": self.distortion.tolist(),
                "R": self.R.tolist(), "t": self.t.tolist()}

    @classmethod
    def from_dict(cls, d: dict, *, kind: str = "camera", name: str = "",
                  repair_rotation: bool = False) -> "DeviceModel":
        label = name or kind
        missing = [k for k in ("size", "K") if k not in d]
        if missing:
            raise ModelError(f"{label}: missing keys {missing} (have {sorted(d)})")
        return cls(size=tuple(d["size"]), K=d["K"], distortion=d.get("distortion", []),
                   R=d.get("R", np.eye(3)), t=d.get("t", np.zeros(3)), kind=kind, name=name,
                   repair_rotation=repair_rotation)

    def __repr__(self) -> str:
        return (f"DeviceModel({self.kind} {self.name!r} {self.size[0]}x{self.size[1]}, "
                f"fx={self.fx:.3f} fy={self.fy:.3f} cx={self.cx:.3f} cy={self.cy:.3f} s={self.skew:.4g}, "
                f"{self.distortion.size} dist terms, t={np.round(self.t, 3).tolist()})")
