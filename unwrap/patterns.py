"""Fringe patterns and the phase <-> projector-coordinate conventions (DESIGN.md).

Pattern n of N at absolute phase ``Phi``:  ``I_n = A + B * cos(Phi - 2*pi*n/N)``.
Fringes varying along projector columns (orientation ``"v"``) have ``Phi = 2*pi*f*u_p / W_p``;
along rows (``"h"``) ``Phi = 2*pi*f*v_p / H_p``; ``f`` = periods across the pattern, pixel centres
at integer coordinates. ``fringe_intensity`` works on numpy arrays and torch tensors.

SYNOPSIS

    >>> import numpy as np
    >>> from unwrap.patterns import fringe_pattern, projector_coordinate
    >>> img = fringe_pattern((912, 1140), frequency=8, step=0, steps=12, orientation="v")
    >>> img.shape
    (1140, 912)
    >>> round(float(projector_coordinate(2 * np.pi * 8, 8, 912)), 9)
    912.0
"""
from __future__ import annotations

import math

import numpy as np

from .errors import UnwrapError

ORIENTATIONS = ("v", "h")


def _check_orientation(orientation: str) -> None:
    if orientation not in ORIENTATIONS:
        raise UnwrapError(f"orientation must be 'v' (fringes along projector columns, gives u_p) "
                          f"or 'h' (along rows, gives v_p); got {orientation!r}")


def phase_shift(step: int, steps: int) -> float:
    """Shift of pattern ``step`` of ``steps``: ``2*pi*step/steps`` (radians)."""
    if steps < 1 or not 0 <= step < steps:
        raise UnwrapError(f"step {step} of {steps}: expected 0 <= step < steps")
    return 2.0 * math.pi * step / steps


def _check_scale(frequency, extent) -> None:
    if not (math.isfinite(frequency) and frequency > 0 and math.isfinite(extent) and extent > 0):
        raise UnwrapError(f"frequency (periods across the pattern) and extent (projector pixels) must be "
                          f"finite and > 0, got {frequency!r} and {extent!r}")


def absolute_phase(coordinate, frequency: float, extent: float):
    """Projector coordinate (px) -> absolute phase ``2*pi*f*coordinate/extent`` (rad)."""
    _check_scale(frequency, extent)
    return coordinate * (2.0 * math.pi * frequency / extent)


def projector_coordinate(phase, frequency: float, extent: float):
    """Absolute phase (rad) -> projector coordinate ``phase*extent/(2*pi*f)`` (px)."""
    _check_scale(frequency, extent)
    return phase * (extent / (2.0 * math.pi * frequency))


def fringe_intensity(phase, step: int, steps: int, A=0.5, B=0.5):
    """``A + B*cos(phase - 2*pi*step/steps)`` for numpy arrays or torch tensors."""
    shifted = phase - phase_shift(step, steps)
    if isinstance(shifted, np.ndarray) or np.isscalar(shifted):
        return A + B * np.cos(shifted)
    import torch
    return A + B * torch.cos(shifted)


def fringe_pattern(size, frequency: float, step: int, steps: int, orientation: str = "v",
                   A: float = 0.5, B: float = 0.5) -> np.ndarray:
    """The projector image (H, W) float64 in [A-B, A+B] for one pattern.

    ARGUMENTS: size = (W, H) of the projector in pixels; frequency = periods across the pattern
    (across W for "v", across H for "h"); step of steps.
    """
    _check_orientation(orientation)
    W, H = (int(v) for v in size)
    if orientation == "v":
        phase = absolute_phase(np.arange(W, dtype=np.float64), frequency, W)[None, :]
    else:
        phase = absolute_phase(np.arange(H, dtype=np.float64), frequency, H)[:, None]
    return np.broadcast_to(fringe_intensity(phase, step, steps, A, B), (H, W)).copy()
