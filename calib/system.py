"""A structured-light system: one camera and one projector in a shared world frame.

The built-in default system is the paper's real system at full precision: the Bouguet-toolbox
results of the DP-TPU repository (github.com/nomineee/DP-TPU, MIT licence, files
``data/calib/CamCalibResult_real.mat`` and ``PrjCalibResult_real.mat``), board pose 1 as world,
with the device datasheet facts (Basler acA640-750um: 4.8 um pixels; TI DLP4500: 912 x 1140
DMD of 10.8 x 6.8 mm). The numbers are shipped in ``calib/data/default_system.json``.

SYNOPSIS

    >>> from calib.system import SystemModel, default_system
    >>> s = default_system()
    >>> s.camera.size, s.projector.size
    ((640, 480), (912, 1140))
    >>> twin = s.ideal()                       # what a Blender twin represents
    >>> twin.projector.skew, twin.projector.distortion.any()
    (0.0, False)
    >>> SystemModel.from_dict(s.to_dict()).camera.fx == s.camera.fx
    True
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from importlib import resources

from .device import DeviceModel
from .errors import FormatError


@dataclass(frozen=True, eq=False)
class SystemModel:
    """Camera + projector, both mapping world (mm) to their own frames.

    ``meta`` holds provenance and device datasheet facts (``pixel_pitch_um`` etc.).
    """

    camera: DeviceModel
    projector: DeviceModel
    meta: dict = field(default_factory=dict)

    @classmethod
    def from_dict(cls, d: dict, *, repair_rotation: bool = False, source: str = "calibration") -> "SystemModel":
        """Build a system from the ``calibration.json`` dictionary (DESIGN.md keys; other keys go
        to ``meta``). ``source`` names the input in error messages."""
        if not isinstance(d, dict):
            raise FormatError(f"{source}: expected a JSON object, got {type(d).__name__}")
        units = d.get("units", "mm")
        if units != "mm":
            raise FormatError(f"{source}: units = {units!r}; only 'mm' is supported")
        missing = [k for k in ("camera", "projector") if k not in d]
        if missing:
            raise FormatError(f"{source}: missing key(s) {missing}; found {sorted(d)}")
        cam = DeviceModel.from_dict(d["camera"], kind="camera", name="camera", repair_rotation=repair_rotation)
        prj = DeviceModel.from_dict(d["projector"], kind="projector", name="projector",
                                    repair_rotation=repair_rotation)
        return cls(cam, prj, {k: v for k, v in d.items() if k not in ("camera", "projector", "units")})

    def to_dict(self, **extra) -> dict:
        """The ``calibration.json`` dictionary (plus ``extra`` top-level keys)."""
        d = {"units": "mm", "camera": self.camera.to_dict(), "projector": self.projector.to_dict()}
        d.update(self.meta)
        d.update(extra)
        return d

    def devices(self) -> dict:
        return {"camera": self.camera, "projector": self.projector}

    @property
    def repairs(self) -> tuple:
        return self.camera.repairs + self.projector.repairs

    def ideal(self, meta: dict | None = None) -> "SystemModel":
        """The same system without skew and lens distortion: the ideal pinholes a Blender twin
        represents. ``meta``: the new system's metadata (default: a copy of this one's)."""
        return SystemModel(self.camera.without_skew_and_distortion(), self.projector.without_skew_and_distortion(),
                           dict(self.meta) if meta is None else dict(meta))


#: Image sizes (W, H) of DLP micromirror arrays that no camera has: TI DLP4500 (912 x 1140,
#: DLPS028 datasheet) and DLP3000 (608 x 684), both diamond arrays. A "camera" of such a size
#: beside a "projector" of another is a pair of files given in the wrong order.
DMD_SIZES = {(912, 1140): "TI DLP4500", (608, 684): "TI DLP3000"}

#: A baseline (distance between the optical centres) at most this fraction of the devices'
#: distance from the world origin counts as zero: nothing can be triangulated.
MIN_BASELINE_FRACTION = 1e-6


def check_rig(system: SystemModel, source: str = "system") -> None:
    """Refuse a camera + projector pair that cannot be a structured-light rig (CalibError naming
    ``source``): the optical centres at one place (zero baseline: every ray pair is parallel), or
    a camera with the size of a projector's micromirror array (``DMD_SIZES``) beside a projector
    that has none (the two files swapped)."""
    import numpy as np

    from .errors import ModelError

    c_cam, c_prj = system.camera.center_world, system.projector.center_world
    baseline = float(np.linalg.norm(c_prj - c_cam))
    scale = max(float(np.linalg.norm(c_cam)), float(np.linalg.norm(c_prj)))
    if baseline <= MIN_BASELINE_FRACTION * scale or baseline == 0.0:
        only = system.meta.get("only_device")
        raise ModelError(f"{source}: camera and projector centres coincide (baseline {baseline:.3g} mm at "
                         f"{scale:.4g} mm from the world origin): a structured-light rig needs a baseline to "
                         "triangulate" + (f" (this is a calibration of the {only} alone, single-device mode)"
                                          if only else ""))
    cam, prj = tuple(system.camera.size), tuple(system.projector.size)
    if cam in DMD_SIZES and prj not in DMD_SIZES:
        raise ModelError(f"{source}: the camera is {cam[0]}x{cam[1]}, the size of a {DMD_SIZES[cam]} "
                         f"micromirror array, and the projector {prj[0]}x{prj[1]}: camera and projector "
                         "swapped? Give the camera's file first")


def default_system() -> SystemModel:
    """The paper's real system at full precision (see the module docstring)."""
    text = resources.files("calib").joinpath("data/default_system.json").read_text()
    return SystemModel.from_dict(json.loads(text))
