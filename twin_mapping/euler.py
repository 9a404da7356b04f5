"""Blender 'XYZ' Euler angles <-> rotation matrices (radians, float64).

Blender's 'XYZ' order applies X first: ``M = Rz(gamma) @ Ry(beta) @ Rx(alpha)``.

``euler_xyz_from_matrix`` uses atan2 everywhere (never a bare arctan, which loses the quadrant for
a device looking up or rotated by more than 90 degrees) and stays exact at gimbal lock
(beta = +-90 deg): there alpha and gamma are coupled, gamma is set to 0 and alpha carries the
whole rotation about the (coincident) axis; ``gimbal_lock`` reports it.

SYNOPSIS

    >>> import numpy as np
    >>> from twin_mapping.euler import euler_xyz_from_matrix, matrix_from_euler_xyz
    >>> M = matrix_from_euler_xyz([0.1, -0.2, 0.3])
    >>> np.allclose(euler_xyz_from_matrix(M)[0], [0.1, -0.2, 0.3])
    True
"""
from __future__ import annotations

import math

import numpy as np

#: |cos(beta)| below which the X and Z rotations are treated as coupled (gimbal lock).
GIMBAL_COS_TOL = 1e-12


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def matrix_from_euler_xyz(angles) -> np.ndarray:
    """(alpha, beta, gamma) radians -> ``Rz(gamma) Ry(beta) Rx(alpha)`` (3,3). The one XYZ-Euler
    builder of the toolkit (``synth.scenes.poses.rotation_xyz_deg`` takes degrees and calls it)."""
    a, b, g = (float(v) for v in np.asarray(angles, dtype=np.float64).reshape(3))
    return _rz(g) @ _ry(b) @ _rx(a)


def euler_xyz_from_matrix(M) -> tuple[np.ndarray, bool]:
    """Rotation matrix (3,3) -> ((alpha, beta, gamma) radians, gimbal_lock).

    beta in [-pi/2, pi/2], alpha and gamma in (-pi, pi]. gamma is computed first; alpha then comes
    from the residual ``Ry(beta)^T Rz(gamma)^T M``, so the angles reproduce ``M`` to rounding even
    where gamma itself is ill-determined (near gimbal lock).
    """
    M = np.asarray(M, dtype=np.float64)
    cos_b = np.hypot(M[0, 0], M[1, 0])
    beta = np.arctan2(-M[2, 0], cos_b)
    lock = bool(cos_b < GIMBAL_COS_TOL)
    gamma = 0.0 if lock else np.arctan2(M[1, 0], M[0, 0])
    Rx = _ry(beta).T @ _rz(gamma).T @ M
    alpha = np.arctan2(Rx[2, 1], Rx[1, 1])
    return np.array([alpha, beta, gamma]), lock


def paper_s1_angles(M) -> np.ndarray:
    """The paper's table S1 formulas, with its bare arctan (radians), for comparison only.

    phi = arctan(r32/r33), theta = arctan(-r31/sqrt(r32^2 + r33^2)), psi = arctan(r21/r11) on the
    device-to-world matrix. Equal to ``euler_xyz_from_matrix`` while |alpha|, |gamma| < 90 deg;
    wrong by 180 deg beyond (arctan cannot see the quadrant).
    """
    r = np.asarray(M, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.array([np.arctan(r[2, 1] / r[2, 2]),
                         np.arctan(-r[2, 0] / np.hypot(r[2, 1], r[2, 2])),
                         np.arctan(r[1, 0] / r[0, 0])])
