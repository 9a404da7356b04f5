"""Non-negative least squares for the small systems of the uncertainty model, in numpy.

``nnls(A, b)`` solves ``min |A x - b|`` subject to ``x >= 0`` by Lawson and Hanson's active-set
method (Lawson & Hanson, *Solving Least Squares Problems*, 1974, ch. 23), as
``scipy.optimize.nnls`` does; for a matrix of full column rank the solution is unique, so the two
agree to rounding (a test). It exists so that ``calib run`` need not import ``scipy.optimize``
(0.2-1 s of start-up for a system of at most 13 unknowns, :mod:`calib.uncertainty.pose_error_model`).

    >>> import numpy as np
    >>> x, rnorm = nnls(np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), np.array([2.0, 1.0, -1.0]))
    >>> x.round(12).tolist(), round(rnorm, 6)
    ([1.5, 0.0], 1.224745)
"""
from __future__ import annotations

import numpy as np


def nnls(A, b, max_iterations: int | None = None) -> tuple[np.ndarray, float]:
    """``(x, |A x - b|)`` with ``x >= 0`` minimising ``|A x - b|``; ``A`` (m, n), ``b`` (m,).
    Raises ``RuntimeError`` after ``max_iterations`` (default ``3 n``) outer iterations, as scipy does."""
    A, b = np.asarray(A, dtype=np.float64), np.asarray(b, dtype=np.float64)
    m, n = A.shape
    max_iterations = 3 * n if max_iterations is None else max_iterations
    tol = 10 * np.finfo(float).eps * max(m, n) * max(np.abs(A).sum(axis=0).max(initial=0.0), 1e-300)
    x = np.zeros(n)
    passive = np.zeros(n, bool)
    w = A.T @ b
    for _ in range(max_iterations + 1):
        candidates = ~passive & (w > tol)
        if not candidates.any():
            break
        j = int(np.argmax(np.where(candidates, w, -np.inf)))
        passive[j] = True
        z = np.zeros(n)
        z[passive] = np.linalg.lstsq(A[:, passive], b, rcond=None)[0]
        if z[j] <= tol:             # rounding: the gradient said it would grow, the solve disagrees
            passive[j], w[j] = False, 0.0
            continue
        while True:
            if np.all(z[passive] > tol):
                break
            # step from x towards z until the first passive variable (the blocking one, k) reaches
            # 0: it leaves the set at exactly 0, whatever the step's rounding left (Lawson-Hanson),
            # and so does any other that the step brought within tol of 0
            hit = passive & (z <= tol)
            ratio = np.full(n, np.inf)
            np.divide(x, np.maximum(x - z, 1e-300), out=ratio, where=hit)
            k = int(np.argmin(ratio))
            x = x + ratio[k] * (z - x)
            x[k] = 0.0
            passive &= x > tol
            x[~passive] = 0.0
            z = np.zeros(n)
            z[passive] = np.linalg.lstsq(A[:, passive], b, rcond=None)[0]
        x = z
        w = A.T @ (b - A @ x)
    else:
        raise RuntimeError(f"nnls: no solution after {max_iterations} iterations")
    return x, float(np.linalg.norm(A @ x - b))
