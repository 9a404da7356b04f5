"""Shared helpers of the synth tests: small scenes and the N-step phase (DESIGN.md formula)."""
import math

import numpy as np

from calib import DeviceModel, default_system
from calib.system import SystemModel
from experiments.blender_parity import downscaled_camera
from unwrap.phase_shift import wrapped_phase


def small_system(scale: int = 4, ideal: bool = False, square_pixels: bool = False) -> SystemModel:
    """The default system with the camera image reduced ``scale`` times (same field of view)."""
    s = default_system()
    cam = downscaled_camera(s.camera, scale, square_pixels=square_pixels)
    prj = s.projector
    if ideal:
        cam, prj = cam.without_skew_and_distortion(), prj.without_skew_and_distortion()
    return SystemModel(cam, prj, dict(s.meta))


def nstep_phase(stack) -> np.ndarray:
    """Wrapped phase of I_n = A + B cos(phi - 2 pi n / N), by unwrap's least-squares formula."""
    return np.asarray(wrapped_phase(np.asarray(stack, dtype=np.float64), saturation=None,
                                    fill_invalid=False).phase)


def wrap(x):
    return np.angle(np.exp(1j * np.asarray(x)))
