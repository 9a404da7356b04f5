"""A structured-light system: one camera and one projector in a shared world frame.

The built-in default system is the paper's real system at full precision: the Bouguet-toolbox
results of the DP-TPU repository (github.com/nomineee/DP-TPU, MIT licence, files
``data/calib/CamCalibResult_real.mat`` and ``PrjCalibResult_real.mat``), board pose 1 as world,
with the device datasheet facts (Basler acA640-750um: 4.8 um pixels; TI DLP4500: 912 x 1140
DMD of 10.8 x 6.8 mm). The numbers are shipped in ``calib/data/default_system.json``.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from importlib import resources

from .device import DeviceModel


@dataclass(frozen=True, eq=False)
class SystemModel:
    """Camera + projector, both mapping world (mm) to their own frames.

    ``meta`` holds provenance and device datasheet facts (``pixel_pitch_um`` etc.).
    """

    camera: DeviceModel
    projector: DeviceModel
    meta: dict = field(default_factory=dict)

    def devices(self) -> dict:
        return {"camera": self.camera, "projector": self.projector}

    @property
    def repairs(self) -> tuple:
        return self.camera.repairs + self.projector.repairs


def default_system() -> SystemModel:
    """The paper's real system at full precision (see the module docstring)."""
    from .io.calibration_json import system_from_dict

    text = resources.files("calib").joinpath("data/default_system.json").read_text()
    return system_from_dict(json.loads(text))
