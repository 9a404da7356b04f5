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


def default_system() -> SystemModel:
    """The paper's real system at full precision (see the module docstring)."""
    text = resources.files("calib").joinpath("data/default_system.json").read_text()
    return SystemModel.from_dict(json.loads(text))
