"""Shared helpers of the synth tests: small scenes and the N-step phase (DESIGN.md formula)."""
import math

import numpy as np

from calib import DeviceModel, default_system
from calib.system import SystemModel


def small_system(scale: int = 4, ideal: bool = False, square_pixels: bool = False) -> SystemModel:
    """The default system with the camera image reduced ``scale`` times (same field of view)."""
    s = default_system()
    cam = s.camera
    K = np.array(cam.K)
    K[0, :] /= scale
    K[1, :] /= scale
    K[0, 2] = (cam.cx + 0.5) / scale - 0.5
    K[1, 2] = (cam.cy + 0.5) / scale - 0.5
    if square_pixels:
        K[1, 1] = K[0, 0]
    cam = cam.with_(size=(cam.width // scale, cam.height // scale), K=K)
    prj = s.projector
    if ideal:
        cam, prj = cam.without_skew_and_distortion(), prj.without_skew_and_distortion()
    return SystemModel(cam, prj, dict(s.meta))


def nstep_phase(stack) -> np.ndarray:
    """Wrapped phase of I_n = A + B cos(phi - 2 pi n / N): atan2(sum I sin, sum I cos)."""
    stack = np.asarray(stack, dtype=np.float64)
    N = stack.shape[0]
    d = 2 * np.pi * np.arange(N) / N
    return np.arctan2(np.tensordot(np.sin(d), stack, 1), np.tensordot(np.cos(d), stack, 1))


def wrap(x):
    return np.angle(np.exp(1j * np.asarray(x)))
