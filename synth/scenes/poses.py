"""Rigid poses of scene objects: object -> world rotation and translation (mm).

``pose = {R = [[...]], t = [...]}`` or ``pose = {rotation_deg = [rx, ry, rz], t = [...]}``; the
Euler angles are Blender's 'XYZ' order (rotate about x first): ``R = Rz @ Ry @ Rx``.
A point of the object maps to the world as ``X_world = R @ X_obj + t``.

SYNOPSIS

    >>> import numpy as np
    >>> from synth.scenes.poses import parse_pose
    >>> R, t = parse_pose({"rotation_deg": [0, 0, 90], "t": [0, 0, 10]}, "pose")
    >>> np.round(R @ [1.0, 0, 0] + t, 12).tolist()
    [0.0, 1.0, 10.0]
"""
from __future__ import annotations

import math

import numpy as np

from calib.rotation import validate_rotation
from unwrap.strict import check_keys
from twin_mapping.euler import matrix_from_euler_xyz

from ..errors import SynthError


def rotation_xyz_deg(angles_deg) -> np.ndarray:
    """Blender 'XYZ' Euler angles (degrees) -> rotation matrix (3,3) ``Rz @ Ry @ Rx``
    (:func:`twin_mapping.euler.matrix_from_euler_xyz` in degrees)."""
    return matrix_from_euler_xyz([math.radians(float(a)) for a in angles_deg])


def _vector(value, n: int, key: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise SynthError(f"{key}: expected {n} numbers, got {value!r}") from None
    if a.size != n or not np.all(np.isfinite(a)):
        raise SynthError(f"{key}: expected {n} finite numbers, got {value!r}")
    return a


def parse_pose(d, key: str) -> tuple[np.ndarray, np.ndarray]:
    """A pose table -> ``(R_world_obj (3,3), t_world_obj (3,))``; missing -> identity, zero."""
    if d is None:
        return np.eye(3), np.zeros(3)
    if not isinstance(d, dict):
        raise SynthError(f"{key}: expected a table {{R = ..., t = ...}} or {{rotation_deg = ..., t = ...}}, got {d!r}")
    check_keys(d, ("R", "t", "rotation_deg"), "scene", SynthError, prefix=f"{key}.")
    if "R" in d and "rotation_deg" in d:
        raise SynthError(f"{key}: give either R or rotation_deg, not both")
    t = _vector(d.get("t", [0, 0, 0]), 3, f"{key}.t")
    if "rotation_deg" in d:
        R = rotation_xyz_deg(_vector(d["rotation_deg"], 3, f"{key}.rotation_deg"))
    elif "R" in d:
        try:
            R = validate_rotation(np.asarray(d["R"], dtype=np.float64), f"{key}.R")
        except ValueError as exc:
            raise SynthError(str(exc)) from None
    else:
        R = np.eye(3)
    return R, t
