"""OpenCV lens distortion (0, 4, 5, 8 or 12 coefficients) on normalised image coordinates.

Coefficient order as OpenCV: ``k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4``. With
``r2 = x^2 + y^2``:

    radial = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3)
    xd = x radial + 2 p1 x y + p2 (r2 + 2 x^2) + s1 r2 + s2 r2^2
    yd = y radial + p1 (r2 + 2 y^2) + 2 p2 x y + s3 r2 + s4 r2^2

``distort`` uses only elementwise arithmetic, so the one implementation serves numpy arrays and
torch tensors alike (gradients flow through it). ``undistort`` inverts it by Newton's method in
float64 (numpy). Two implementations with one contract: the numpy reference below (central-difference
Jacobian, all points iterate until the worst one converges; readable, no compiled code) and, for
arrays of at least ``FAST_MIN_POINTS`` points when numba is installed, the compiled kernel
``calib._undistort_kernel`` (analytic Jacobian, each point stops when it converges; ~10-50x
faster on a 640x480 image). Both flag a point converged when its residual is below 1e-12; they
agree to 1e-12 and flag the same points wherever the lens is one-to-one, and flag alike where no
preimage exists. Beyond a fold of the polynomial (a point with several preimages) which one Newton
reaches depends on its path, so there the two may differ; both only ever return true preimages
(tests/test_distortion_fast.py).

SYNOPSIS

    >>> import numpy as np
    >>> from calib.distortion import distort, undistort
    >>> xy = np.array([[0.1, -0.05]])
    >>> coeffs = [-0.13, -0.56, -0.0014, -0.0004, 0.0]
    >>> xy_back, ok = undistort(distort(xy, coeffs), coeffs)
    >>> bool(ok.all()) and bool(np.allclose(xy_back, xy, atol=1e-12))
    True
"""
from __future__ import annotations

import numpy as np

from .errors import ModelError

VALID_LENGTHS = (0, 4, 5, 8, 12)


def check_coefficients(coeffs, name: str = "distortion") -> np.ndarray:
    """Validate a distortion vector; return it as float64 (n,) with n in 0, 4, 5, 8, 12."""
    try:
        d = np.asarray(coeffs if coeffs is not None else [], dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ModelError(f"{name}: cannot be read as numbers ({exc})") from None
    if d.size not in VALID_LENGTHS:
        raise ModelError(f"{name}: {d.size} coefficients; expected one of {VALID_LENGTHS} "
                         "(OpenCV order k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4)")
    if not np.all(np.isfinite(d)):
        raise ModelError(f"{name}: non-finite coefficients {d.tolist()}")
    return d


def _padded(coeffs) -> list[float]:
    c = [float(v) for v in np.asarray(coeffs, dtype=np.float64).reshape(-1)]
    return c + [0.0] * (12 - len(c))


def distort(xy, coeffs):
    """Apply distortion to normalised coordinates ``xy`` (..., 2) -> (..., 2).

    Works on numpy arrays and torch tensors (same dtype and device as the input).
    """
    c = _padded(coeffs)
    if not any(c):
        return xy
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = c
    x = xy[..., 0]
    y = xy[..., 1]
    r2 = x * x + y * y
    r4 = r2 * r2
    r6 = r4 * r2
    radial = (1 + k1 * r2 + k2 * r4 + k3 * r6)
    if k4 or k5 or k6:
        radial = radial / (1 + k4 * r2 + k5 * r4 + k6 * r6)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r4
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + s3 * r2 + s4 * r4
    if isinstance(xy, np.ndarray):
        return np.stack([xd, yd], axis=-1)
    import torch  # torch input: stay on its device and dtype
    return torch.stack([xd, yd], dim=-1)


FAST_MIN_POINTS = 4096  # below this the numpy reference is fast enough and numba is not imported


def undistort_fast_available() -> bool:
    """True when numba is importable (the compiled undistortion kernel can run)."""
    try:
        from . import _undistort_kernel  # noqa: F401
    except ImportError:
        return False
    return True


def undistort(xyd, coeffs, *, iterations: int = 30, tol: float = 1e-14, fast="auto"):
    """Invert ``distort`` by Newton's method (numpy, float64).

    ARGUMENTS
    - xyd: distorted normalised coordinates (..., 2).
    - coeffs: distortion coefficients (OpenCV order).
    - iterations: at most this many Newton steps per point.
    - tol: a point stops iterating once its residual is below ``tol`` (reference: once every
      point's is).
    - fast: "auto" (compiled kernel for ``FAST_MIN_POINTS`` points or more when numba is
      installed), True (kernel, or ModelError when numba is missing), False (numpy reference).

    RETURNED VALUE: ``(xy, converged)``: undistorted coordinates (..., 2) and a boolean mask
    (...,) of the points whose residual ``|distort(xy) - xyd|`` fell below ``1e-12``. Points that
    did not converge (outside the region where the lens model is invertible, or non-finite
    input) keep their last iterate; callers must use the mask, never the value alone.
    """
    if fast not in ("auto", True, False):
        raise ModelError(f"undistort: fast must be 'auto', True or False, got {fast!r}")
    xyd = np.asarray(xyd, dtype=np.float64)
    if xyd.ndim == 0 or xyd.shape[-1] != 2:
        raise ModelError(f"undistort: expected points of shape (..., 2), got {xyd.shape}")
    c = _padded(coeffs)
    if not any(c):
        return xyd.copy(), np.all(np.isfinite(xyd), axis=-1)
    n_points = xyd.size // 2
    if fast is True or (fast == "auto" and n_points >= FAST_MIN_POINTS and undistort_fast_available()):
        if not undistort_fast_available():
            raise ModelError("undistort: fast=True needs numba, which is not installed")
        from ._undistort_kernel import undistort_fast
        flat = np.ascontiguousarray(xyd.reshape(-1, 2))
        xy, ok = undistort_fast(flat, np.asarray(c, dtype=np.float64), iterations, tol)
        return xy.reshape(xyd.shape), ok.reshape(xyd.shape[:-1])
    return _undistort_reference(xyd, c, iterations, tol)


def _undistort_reference(xyd: np.ndarray, c: list, iterations: int, tol: float):
    """The numpy reference of :func:`undistort` (``c``: 12 padded coefficients, not all zero)."""
    xy = xyd.copy()
    h = 1e-7
    ex = np.array([h, 0.0])
    ey = np.array([0.0, h])
    for _ in range(iterations):
        r = distort(xy, c) - xyd
        if np.nanmax(np.abs(r), initial=0.0) < tol:
            break
        # Jacobian by central differences: exact enough for Newton (the residual itself is exact)
        jx = (distort(xy + ex, c) - distort(xy - ex, c)) / (2 * h)
        jy = (distort(xy + ey, c) - distort(xy - ey, c)) / (2 * h)
        a, b, cc, d = jx[..., 0], jy[..., 0], jx[..., 1], jy[..., 1]
        det = a * d - b * cc
        with np.errstate(divide="ignore", invalid="ignore"):
            dx = (d * r[..., 0] - b * r[..., 1]) / det
            dy = (-cc * r[..., 0] + a * r[..., 1]) / det
        step = np.stack([dx, dy], axis=-1)
        step = np.where(np.isfinite(step), step, 0.0)
        xy = xy - step
    with np.errstate(invalid="ignore"):
        resid = np.abs(distort(xy, c) - xyd).max(axis=-1)
        converged = np.isfinite(resid) & (resid < 1e-12)
    return xy, converged
