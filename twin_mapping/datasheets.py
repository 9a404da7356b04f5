"""Device datasheet facts: pixel pitch (um) per axis, from which focal lengths in mm follow.

- Basler acA640-750um: 640 x 480, 4.8 x 4.8 um pixels (Basler datasheet; paper eq. S1).
- TI DLP4500: 912 x 1140 micromirrors (diamond array) on a 10.8 x 6.8 mm active area
  (TI DLPS028 datasheet; paper eq. S2), i.e. an equivalent pitch of 10.8/912 x 6.8/1140 mm.
"""
from __future__ import annotations

from dataclasses import dataclass

from .errors import TwinError


@dataclass(frozen=True)
class Datasheet:
    """Pixel pitch (um, x and y) of a device's sensor or DMD, and its model name."""

    model: str
    resolution_px: tuple
    pixel_pitch_um: tuple

    @property
    def sensor_size_mm(self) -> tuple:
        return tuple(n * p / 1000.0 for n, p in zip(self.resolution_px, self.pixel_pitch_um))

    @classmethod
    def from_sensor_size(cls, model: str, resolution_px, sensor_size_mm) -> "Datasheet":
        w, h = resolution_px
        return cls(model, (int(w), int(h)), (sensor_size_mm[0] / w * 1000.0, sensor_size_mm[1] / h * 1000.0))

    def check(self, size, device: str) -> None:
        if tuple(size) != tuple(self.resolution_px):
            raise TwinError(f"{device}: the calibration's image size {tuple(size)} differs from the "
                            f"datasheet's {self.resolution_px} ({self.model}); give the right datasheet")
        if min(self.pixel_pitch_um) <= 0:
            raise TwinError(f"{device}: pixel pitch must be > 0, got {self.pixel_pitch_um} um")


BASLER_ACA640_750UM = Datasheet("Basler acA640-750um", (640, 480), (4.8, 4.8))
DLP4500 = Datasheet.from_sensor_size("TI DLP4500 (DMD, diamond pixel array)", (912, 1140), (10.8, 6.8))


def datasheets_for(system) -> dict:
    """Datasheets for the devices of a system: from ``system.meta['datasheets']`` when present,
    else the paper's devices when the sizes match, else a nominal 1 um pitch (reported as such)."""
    out = {}
    meta = getattr(system, "meta", {}).get("datasheets", {})
    for kind, device, default in (("camera", system.camera, BASLER_ACA640_750UM),
                                  ("projector", system.projector, DLP4500)):
        m = meta.get(kind)
        if m and "pixel_pitch_um" in m:
            out[kind] = Datasheet(m.get("model", kind), tuple(m["resolution_px"]), tuple(m["pixel_pitch_um"]))
        elif m and "dmd_size_mm" in m:
            out[kind] = Datasheet.from_sensor_size(m.get("model", kind), m["resolution_px"], m["dmd_size_mm"])
        elif tuple(device.size) == default.resolution_px:
            out[kind] = default
        else:
            out[kind] = Datasheet(f"unknown {kind} (nominal 1 um pitch: focal lengths in mm are nominal)",
                                  tuple(device.size), (1.0, 1.0))
    return out
