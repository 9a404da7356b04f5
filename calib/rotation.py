"""Rotation matrices: validation, repair, and axis-angle conversions (float64).

A rotation here is a 3x3 orthonormal matrix with determinant +1. ``validate_rotation`` refuses
anything else with a message that names the defect; ``nearest_rotation`` repairs a rounded
matrix only when asked, and says how far it moved it.

SYNOPSIS

    >>> import numpy as np
    >>> from calib.rotation import validate_rotation, nearest_rotation
    >>> R = validate_rotation(np.eye(3), "R_cam_world")
    >>> R_fixed, moved_deg = nearest_rotation(np.diag([1.0, 1.0, 0.999]))
    >>> round(moved_deg, 6)
    0.0
"""
from __future__ import annotations

import numpy as np

from .errors import ModelError

#: Default tolerance on ``max|R^T R - I|`` and ``|det R - 1|``.
ORTHONORMAL_TOL = 1e-6


def _as_matrix(R, name: str) -> np.ndarray:
    try:
        R = np.asarray(R, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ModelError(f"{name}: cannot be read as a 3x3 array of numbers ({exc})") from None
    if R.shape != (3, 3):
        raise ModelError(f"{name}: expected a 3x3 rotation matrix, got shape {R.shape}")
    if not np.all(np.isfinite(R)):
        bad = [tuple(int(i) for i in ij) for ij in np.argwhere(~np.isfinite(R))]
        raise ModelError(f"{name}: non-finite entries at {bad}: {R.tolist()}")
    return R


def rotation_defects(R) -> tuple[float, float]:
    """Return ``(max|R^T R - I|, det R)`` of a 3x3 matrix."""
    R = np.asarray(R, dtype=np.float64)
    return float(np.max(np.abs(R.T @ R - np.eye(3)))), float(np.linalg.det(R))


def nearest_rotation(R) -> tuple[np.ndarray, float]:
    """Nearest rotation (Frobenius norm) to a 3x3 matrix with positive determinant, by SVD.

    RETURNED VALUE: ``(R_rotation, moved_deg)``: the repaired matrix and the largest angle, in
    degrees, between an axis (column) of the input and the same axis of the repaired rotation. A matrix with determinant <= 0 is a reflection or degenerate: no rotation
    is "near" it and ModelError is raised.
    """
    R = _as_matrix(R, "rotation")
    det = float(np.linalg.det(R))
    if det <= 0:
        raise ModelError(
            f"rotation: det = {det:.6g} <= 0, a reflection or a degenerate matrix, not a rotation; "
            "it cannot be repaired (check the sign convention of the source)")
    U, _, Vt = np.linalg.svd(R)
    R_rot = U @ Vt
    # how far the repair moved it: the largest angle between an axis (column) of the input and
    # the same axis of the repaired rotation
    cols = R / np.linalg.norm(R, axis=0, keepdims=True)
    cos = np.clip(np.sum(cols * R_rot, axis=0), -1.0, 1.0)
    return R_rot, float(np.degrees(np.max(np.arccos(cos))))


def validate_rotation(R, name: str = "R", *, tol: float = ORTHONORMAL_TOL,
                      repair: bool = False, report: list | None = None) -> np.ndarray:
    """Check that ``R`` is a rotation; return it as a float64 (3,3) array.

    ARGUMENTS
    - R: anything convertible to a (3,3) float array.
    - name: how the matrix is called in messages (``"camera.R"``).
    - tol: tolerance on ``max|R^T R - I|`` and ``|det R - 1|``.
    - repair: if True, a matrix that fails the test but has det > 0 is replaced by the nearest
      rotation (SVD), and a line saying so, with the angle moved, is appended to ``report``.

    A reflection (det < 0), a non-finite entry or a wrong shape is always refused.
    """
    R = _as_matrix(R, name)
    err, det = rotation_defects(R)
    if det < 0:
        raise ModelError(
            f"{name}: det = {det:.6f} < 0: this matrix is a reflection, not a rotation "
            f"(a flipped axis or handedness); rows {np.round(R, 6).tolist()}")
    if err <= tol and abs(det - 1.0) <= tol:
        return R
    if not repair:
        raise ModelError(
            f"{name}: not a rotation: max|R^T R - I| = {err:.3g}, det = {det:.6f} "
            f"(tolerance {tol:g}); rows {np.round(R, 6).tolist()}. Rounded printed values? "
            "Use full-precision data, or ask for repair (--repair-rotation: nearest rotation by SVD)")
    R_rot, moved = nearest_rotation(R)
    line = (f"{name}: repaired to the nearest rotation (SVD): was max|R^T R - I| = {err:.3g}, "
            f"det = {det:.6f}; moved by {moved:.4f} deg")
    if report is not None:
        report.append(line)
    return R_rot


def rotvec_from_matrix(R) -> np.ndarray:
    """Axis-angle vector (3,) in radians of a rotation matrix (robust near 0 and pi)."""
    R = np.asarray(R, dtype=np.float64)
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-6:
        return 0.5 * w
    if np.pi - angle > 1e-4:
        return angle * w / (2.0 * np.sin(angle))
    # near pi: axis from the diagonal of (R + I)/2 = a a^T
    B = (R + np.eye(3)) / 2.0
    i = int(np.argmax(np.diag(B)))
    a = B[:, i] / np.sqrt(B[i, i])
    if np.dot(w, a) < 0:  # keep the sign consistent with the (small) antisymmetric part
        a = -a
    return angle * a


def matrix_from_rotvec(rvec) -> np.ndarray:
    """Rotation matrix (3,3) from an axis-angle vector in radians (Rodrigues)."""
    r = np.asarray(rvec, dtype=np.float64).reshape(3)
    angle = np.linalg.norm(r)
    if angle < 1e-12:
        k = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
        return np.eye(3) + k
    a = r / angle
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def angle_between_deg(R_a, R_b) -> float:
    """Angle in degrees of the rotation ``R_a^T R_b``."""
    M = np.asarray(R_a, dtype=np.float64).T @ np.asarray(R_b, dtype=np.float64)
    return float(np.degrees(np.arccos(np.clip((np.trace(M) - 1.0) / 2.0, -1.0, 1.0))))
