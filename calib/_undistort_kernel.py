"""numba kernel of :func:`calib.distortion.undistort` (imported only when numba is installed).

Per point, Newton's method on ``distort(xy) = xyd`` from ``xy = xyd`` with the ANALYTIC Jacobian of
the OpenCV model (``calib.distortion``'s formula, k1..k6 rational, p1 p2, s1..s4; the model has no
tilt terms), stopping as soon as that point's residual ``max(|distort(xy) - xyd|)`` is below
``tol`` (the reference stops when the worst point of the whole array is). A non-finite Newton
component is replaced by 0, as in the reference, and a point whose iterate stops moving stops
early; after at most ``iterations`` steps the residual is evaluated once more and the point is
flagged converged when it is finite and below ``1e-12`` (the reference's criterion). Points run
in parallel (``prange``); compiled code is cached on disk (``cache=True``: only the first use on
a machine compiles, a few seconds).

Jacobian, with ``r2 = x^2 + y^2``, ``num = 1 + k1 r2 + k2 r2^2 + k3 r2^3``,
``den = 1 + k4 r2 + k5 r2^2 + k6 r2^3``, ``radial = num / den`` and
``g = d radial / d r2 = (num' den - num den') / den^2`` (``num' = k1 + 2 k2 r2 + 3 k3 r2^2``,
``den' = k4 + 2 k5 r2 + 3 k6 r2^2``):

    d xd/dx = radial + 2 x^2 g + 2 p1 y + 6 p2 x + 2 x (s1 + 2 s2 r2)
    d xd/dy = 2 x y g + 2 p1 x + 2 p2 y + 2 y (s1 + 2 s2 r2)
    d yd/dx = 2 x y g + 2 p1 x + 2 p2 y + 2 x (s3 + 2 s4 r2)
    d yd/dy = radial + 2 y^2 g + 6 p1 y + 2 p2 x + 2 y (s3 + 2 s4 r2)
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

_JIT = dict(cache=True, error_model="numpy", nogil=True)


@nb.njit(inline="always", **_JIT)
def _distort_jacobian(x, y, c):
    """(xd, yd, d xd/dx, d xd/dy, d yd/dx, d yd/dy) of the 12-term model ``c`` at (x, y)."""
    k1, k2, p1, p2, k3, k4, k5, k6 = c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]
    s1, s2, s3, s4 = c[8], c[9], c[10], c[11]
    r2 = x * x + y * y
    r4 = r2 * r2
    r6 = r4 * r2
    num = 1.0 + k1 * r2 + k2 * r4 + k3 * r6
    den = 1.0 + k4 * r2 + k5 * r4 + k6 * r6
    radial = num / den
    dnum = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4
    dden = k4 + 2.0 * k5 * r2 + 3.0 * k6 * r4
    g = (dnum * den - num * dden) / (den * den)
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) + s1 * r2 + s2 * r4
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y + s3 * r2 + s4 * r4
    sx = 2.0 * (s1 + 2.0 * s2 * r2)
    sy = 2.0 * (s3 + 2.0 * s4 * r2)
    cross = 2.0 * x * y * g + 2.0 * p1 * x + 2.0 * p2 * y
    a = radial + 2.0 * x * x * g + 2.0 * p1 * y + 6.0 * p2 * x + x * sx
    b = cross + y * sx
    cc = cross + x * sy
    d = radial + 2.0 * y * y * g + 6.0 * p1 * y + 2.0 * p2 * x + y * sy
    return xd, yd, a, b, cc, d


@nb.njit(**_JIT)
def distort_jacobian_array(xy, c, out):
    """``out[i] = (xd, yd, J00, J01, J10, J11)`` at ``xy[i]`` (N,2) -> (N,6) (tests)."""
    for i in range(xy.shape[0]):
        r = _distort_jacobian(xy[i, 0], xy[i, 1], c)
        for j in range(6):
            out[i, j] = r[j]


@nb.njit(parallel=True, **_JIT)
def undistort_points(xyd, c, iterations, tol, xy, converged):
    """Newton per point: ``xyd`` (N,2) float64, ``c`` (12,) -> ``xy`` (N,2), ``converged`` (N,)."""
    for i in nb.prange(xyd.shape[0]):
        ux = xyd[i, 0]
        uy = xyd[i, 1]
        x = ux
        y = uy
        for _ in range(iterations):
            fx, fy, a, b, cc, d = _distort_jacobian(x, y, c)
            rx = fx - ux
            ry = fy - uy
            if abs(rx) < tol and abs(ry) < tol:  # False for NaN
                break
            det = a * d - b * cc
            dx = (d * rx - b * ry) / det
            dy = (-cc * rx + a * ry) / det
            if not math.isfinite(dx):
                dx = 0.0
            if not math.isfinite(dy):
                dy = 0.0
            nx = x - dx
            ny = y - dy
            if nx == x and ny == y:  # stuck: every further step would be the same
                break
            x = nx
            y = ny
        fx, fy, a, b, cc, d = _distort_jacobian(x, y, c)
        xy[i, 0] = x
        xy[i, 1] = y
        converged[i] = abs(fx - ux) < 1e-12 and abs(fy - uy) < 1e-12  # False for NaN


def undistort_fast(xyd: np.ndarray, c12: np.ndarray, iterations: int, tol: float):
    """``xyd`` (N,2) float64 C-contiguous, ``c12`` (12,) float64 -> (xy (N,2), converged (N,))."""
    xy = np.empty_like(xyd)
    ok = np.empty(xyd.shape[0], dtype=np.bool_)
    undistort_points(xyd, c12, int(iterations), float(tol), xy, ok)
    return xy, ok
