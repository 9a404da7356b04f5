"""Predicted fringe-order error rates of MF, MW, NT and complementary Gray code from phase noise.

Noise model: each frame carries independent Gaussian noise sigma (intensity units); the
least-squares fit then gives ``sigma_phi^2 = 2 sigma^2 / (N B^2)`` at high SNR (equal shifts).
We use the exact distribution of the phase error of a sinusoid in complex Gaussian noise,
whose only parameter is ``rho = 1 / (2 sigma_phi^2)``::

    p(e) = exp(-rho)/(2 pi) + cos(e) sqrt(rho/(4 pi)) exp(-rho sin^2 e) (1 + erf(sqrt(rho) cos e))

(it tends to a Gaussian of variance sigma_phi^2 at high SNR and to uniform at low SNR), so the
prediction holds from error rates of 1e-6 up to 0.5.

A rounding step ``k = Round((r*Phi_c - phi)/(2 pi))`` fails when ``|r*e_c - e| > pi`` (the
rounding margin); the error of a method is the probability that any of its steps fails:

- MF (ladder f_0 <= 1 < f_1 < ...): chained exactly (the error of one level feeds the next);
- MW: beat error ``e1 - e2`` (three wavelengths: ``e1 - 2 e2 + e3``), steps as above;
- NT: ``|f1 e2 - f2 e1| > pi``;
- complementary Gray code (bits right): ``|e| > pi/2``.

Pixels are interior (their base phase is not within the noise of the 2*pi cut of the base
pattern); :func:`unwrap.monte_carlo.monte_carlo_error_rate` simulates real intensity stacks the
same way.

SYNOPSIS (the paper's set: MF 1, 8, 48 periods, N = 12, noise 2 grey levels, modulation 60)

    >>> from unwrap.reliability import error_rate, phase_sigma
    >>> s = phase_sigma(2.0, 12, 60.0)
    >>> round(s, 5)
    0.01361
    >>> error_rate("mf", (1, 8, 48), s) < 1e-12
    True
"""
from __future__ import annotations

import math

import numpy as np

from .errors import UnwrapError
from .phase_shift import equal_shifts, least_squares_weights

_GRID = 4001


def phase_sigma(sigma, steps: int, B) -> float:
    """Phase noise (rad) of N-step least squares: ``sqrt(2 sigma^2 / (N B^2))`` (high SNR)."""
    if steps < 3 or not B > 0 or sigma < 0:
        raise UnwrapError(f"phase_sigma needs steps >= 3, B > 0, sigma >= 0; got {steps}, {B}, {sigma}")
    return math.sqrt(2.0 * sigma ** 2 / (steps * B ** 2))


_erf = np.frompyfunc(math.erf, 1, 1)
"""Elementwise ``math.erf`` (within 1 ulp of ``scipy.special.erf``; importing scipy.special cost
~0.3 s of every ``calib unwrap``, for 4001-point grids)."""


def erf(x):
    """Error function of an array (float64)."""
    return np.asarray(_erf(np.asarray(x, dtype=np.float64)), dtype=np.float64)


def phase_error_pdf(e, sigma_phi: float):
    """Exact density of the wrapped phase error e in (-pi, pi] for phase noise ``sigma_phi`` (rad)."""
    e = np.asarray(e, dtype=np.float64)
    if sigma_phi <= 0:
        raise UnwrapError(f"sigma_phi must be > 0, got {sigma_phi}")
    rho = 0.5 / sigma_phi ** 2
    c = np.cos(e)
    return (math.exp(-rho) / (2 * math.pi)
            + c * math.sqrt(rho / (4 * math.pi)) * np.exp(-rho * np.sin(e) ** 2)
            * (1.0 + erf(math.sqrt(rho) * c)))


def _cumulative(x, p):
    """Left and right cumulative trapezoid integrals of p on grid x."""
    seg = 0.5 * (p[1:] + p[:-1]) * np.diff(x)
    left = np.concatenate([[0.0], np.cumsum(seg)])
    right = np.concatenate([np.cumsum(seg[::-1])[::-1], [0.0]])
    return left, right


class _Dist:
    """Density and CDF of one phase error on a grid over its support."""

    def __init__(self, sigma_phi: float):
        L = min(math.pi, 14.0 * sigma_phi)
        self.x = np.linspace(-L, L, _GRID)
        p = phase_error_pdf(self.x, sigma_phi)
        self.p = p
        self.cdf, self.sf = _cumulative(self.x, p)
        total = self.cdf[-1]
        self.p, self.cdf, self.sf = p / total, self.cdf / total, self.sf / total

    def F(self, v):
        """P(e < v)."""
        return np.interp(v, self.x, self.cdf, left=0.0, right=1.0)

    def S(self, v):
        """P(e > v), summed from the right (no cancellation in the tail)."""
        return np.interp(v, self.x, self.sf, left=1.0, right=0.0)

    def integrate(self, values):
        return float(np.trapz(self.p * values, self.x))


def _sigmas(sigma_phi, n):
    s = np.broadcast_to(np.asarray(sigma_phi, dtype=np.float64), (n,)).astype(np.float64)
    if np.any(~np.isfinite(s)) or np.any(s <= 0):
        raise UnwrapError(f"phase noise must be finite and > 0 rad, got {s.tolist()}")
    return s


def mf_error_rate(frequencies, sigma_phi) -> float:
    """Probability that hierarchical MF over ``frequencies`` gives a wrong final k."""
    f = np.asarray(frequencies, dtype=np.float64)
    s = _sigmas(sigma_phi, f.size)
    d0 = _Dist(s[0])
    g_x, g_p = d0.x, d0.p  # density of the current absolute-phase error on "no failure so far"
    fail = 0.0
    for i in range(1, f.size):
        r = f[i] / f[i - 1]
        d = _Dist(s[i])
        G, Gs = _cumulative(g_x, g_p)
        # step fails when e_prev < (e - pi)/r or e_prev > (e + pi)/r
        below = np.interp((d.x - math.pi) / r, g_x, G, left=0.0, right=G[-1])
        above = np.interp((d.x + math.pi) / r, g_x, Gs, left=Gs[0], right=0.0)
        fail += float(np.trapz(d.p * (below + above), d.x))
        g_x, g_p = d.x, d.p * np.maximum(G[-1] - below - above, 0.0)
    return float(min(1.0, max(0.0, fail)))


def _two_error_fail(a: float, b: float, d_a: _Dist, d_b: _Dist) -> float:
    """P(|a e_a - b e_b| > pi) for independent e_a, e_b (tails summed directly)."""
    fail = d_b.F((-math.pi + a * d_a.x) / b) + d_b.S((math.pi + a * d_a.x) / b)
    return float(min(1.0, max(0.0, d_a.integrate(fail))))


def mw_error_rate(frequencies, sigma_phi) -> float:
    """Probability of a wrong k for two- or three-wavelength heterodyne (frequencies any order)."""
    f = np.asarray(frequencies, dtype=np.float64)
    order = np.argsort(-f)
    f = f[order]
    s = _sigmas(sigma_phi, f.size)[order]
    d = [_Dist(v) for v in s]
    if f.size == 2:
        f_eq = f[0] - f[1]
        # final step: |(f1/f_eq)(e1 - e2) - e1| = |(f2/f_eq) e1 - (f1/f_eq) e2|
        return _two_error_fail(f[1] / f_eq, f[0] / f_eq, d[0], d[1])
    if f.size != 3:
        raise UnwrapError(f"MW takes 2 or 3 wavelengths, got {f.size}")
    f12, f23 = f[0] - f[1], f[1] - f[2]
    f123 = abs(f12 - f23)
    sign = 1.0 if f12 > f23 else -1.0
    c = f12 / f123
    nodes, weights = np.polynomial.legendre.leggauss(96)
    fail_A = np.zeros_like(d[1].x)
    cs = c * sign
    for j, e2 in enumerate(d[1].x):
        # step B ok: |(f2/f12) e1 - (f1/f12) e2| <= pi  ->  e1 in [lo, hi]
        lo = ((f[0] / f12) * e2 - math.pi) / (f[1] / f12)
        hi = ((f[0] / f12) * e2 + math.pi) / (f[1] / f12)
        lo, hi = max(lo, d[0].x[0]), min(hi, d[0].x[-1])
        if hi <= lo:
            continue
        e1 = 0.5 * (hi - lo) * nodes + 0.5 * (hi + lo)
        w = 0.5 * (hi - lo) * weights
        p1 = np.interp(e1, d[0].x, d[0].p)
        # step A fails: |cs*(e12 - e2 + e3) - e12| > pi with e12 = e1 - e2 (linear in e3)
        e12 = e1 - e2
        base = cs * (e12 - e2) - e12
        b1, b2 = (math.pi - base) / cs, (-math.pi - base) / cs
        pA = d[2].F(np.minimum(b1, b2)) + d[2].S(np.maximum(b1, b2))
        fail_A[j] = float(np.sum(w * p1 * pA))
    fail_B = _two_error_fail(f[1] / f12, f[0] / f12, d[0], d[1])
    return float(min(1.0, max(0.0, fail_B + d[1].integrate(fail_A))))


def nt_error_rate(frequencies, sigma_phi) -> float:
    """Probability of a wrong k for number-theoretic unwrapping of a coprime pair."""
    f1, f2 = (float(v) for v in frequencies)
    s = _sigmas(sigma_phi, 2)
    return _two_error_fail(f2, f1, _Dist(s[0]), _Dist(s[1]))  # |f1 e2 - f2 e1| > pi


def complementary_gray_error_rate(sigma_phi, n_offsets: int = 720) -> float:
    """Probability of a wrong k with complementary Gray code (code bits right, pixels uniform).

    The decoder picks K2 where the measured |phi| <= pi/2 and K1 elsewhere; it fails when the
    picked code's coarse phase is more than pi from the noisy absolute phase. Averaged over the
    pixel's position t in the period (exact decision, integrated on a grid).
    """
    d = _Dist(float(sigma_phi))
    t = (np.arange(n_offsets) + 0.5) / n_offsets  # position in the period, u/P - K1
    e = d.x[None, :]
    Phi = 2 * math.pi * t[:, None]  # true absolute phase minus 2*pi*K1
    phi = np.mod(Phi + e + math.pi, 2 * math.pi) - math.pi
    K2 = (t[:, None] >= 0.5).astype(np.float64)
    coarse = np.where(np.abs(phi) <= math.pi / 2, 2 * math.pi * K2, math.pi)
    k = np.round((coarse - phi) / (2 * math.pi))
    wrong = np.abs(phi + 2 * math.pi * k - Phi) > math.pi
    per_t = np.trapz(d.p[None, :] * wrong, d.x, axis=1)
    return float(per_t.mean())


def error_rate(method: str, frequencies, sigma_phi) -> float:
    """Dispatch: method "mf", "mw", "nt" or "cgray" (complementary Gray code)."""
    if method == "mf":
        return mf_error_rate(frequencies, sigma_phi)
    if method == "mw":
        return mw_error_rate(frequencies, sigma_phi)
    if method == "nt":
        return nt_error_rate(frequencies, sigma_phi)
    if method == "cgray":
        return complementary_gray_error_rate(np.max(sigma_phi))
    raise UnwrapError(f"unknown method {method!r}: expected mf, mw, nt or cgray")


def _model_rate(method: str, frequencies, steps, sigma: float, B: float) -> float:
    """Predicted error rate with modulation ``B`` at every frequency (``steps[i]`` frames each)."""
    s_phi = [phase_sigma(sigma, int(n), B) for n in steps]
    return error_rate(method, frequencies, np.asarray(s_phi))


def modulation_threshold(method: str, frequencies, steps, sigma: float, max_error_rate: float,
                         *, rel_tol: float = 0.01) -> float:
    """Smallest modulation B (intensity units) at which ``method`` keeps its predicted
    fringe-order error rate at or below ``max_error_rate``.

    ARGUMENTS: method "mf", "mw", "nt" or "cgray"; frequencies (periods across the pattern);
    steps (frames per frequency, one per frequency or one for all); sigma = intensity noise per
    frame (same units as B); max_error_rate in (0, 0.5). B is taken equal at every frequency
    (the highest frequency's B is usually the lowest, so a pixel whose every B passes the
    threshold does at least this well). Bisection in log B to ``rel_tol``.

    >>> round(modulation_threshold("mf", (1, 8, 48), 12, 2.0, 1e-3), 1)
    7.1
    """
    f = np.asarray(frequencies, dtype=np.float64).reshape(-1)
    steps = np.broadcast_to(np.asarray(steps, dtype=np.int64).reshape(-1), f.shape)
    if not (0.0 < max_error_rate < 0.5):
        raise UnwrapError(f"max_error_rate must lie in (0, 0.5), got {max_error_rate!r}")
    if not (math.isfinite(sigma) and sigma > 0):
        raise UnwrapError(f"noise sigma must be finite and > 0, got {sigma!r}")
    lo, hi = 1e-3 * sigma, 1e6 * sigma
    if _model_rate(method, f, steps, sigma, hi) > max_error_rate:
        raise UnwrapError(f"{method} {f.tolist()}: no modulation reaches the error rate {max_error_rate:g}")
    while hi / lo > 1.0 + rel_tol:
        mid = math.sqrt(lo * hi)
        if _model_rate(method, f, steps, sigma, mid) > max_error_rate:
            lo = mid
        else:
            hi = mid
    return hi


def predicted_error_rate(method: str, frequencies, steps, sigma: float, modulation, *, bins: int = 16) -> float:
    """Upper bound of the mean predicted error rate over pixels of the given modulations B.

    The pixels are binned by B (log-spaced between the smallest and the largest) and each bin
    counted at its lower edge (the error rate falls as B grows), so the result bounds the mean
    from above; once the pixels left would add less than 5 % they are all counted at the current
    edge (still a bound; the model is evaluated a few times, not once per bin). ``modulation``
    (n,) in the units of ``sigma``, > 0. B equal at every frequency as in :func:`modulation_threshold`.
    """
    f = np.asarray(frequencies, dtype=np.float64).reshape(-1)
    steps = np.broadcast_to(np.asarray(steps, dtype=np.int64).reshape(-1), f.shape)
    B = np.asarray(modulation, dtype=np.float64).reshape(-1)
    B = B[np.isfinite(B) & (B > 0)]
    if B.size == 0:
        return float("nan")
    edges = np.geomspace(B.min(), max(B.max(), B.min() * (1 + 1e-9)), bins + 1)
    counts, _ = np.histogram(B, edges)
    total, left = 0.0, int(counts.sum())
    for edge, count in zip(edges[:-1], counts):
        if not count:
            continue
        rate = _model_rate(method, f, steps, sigma, edge)
        if rate * left <= 0.05 * (total + rate * count):   # the rest is negligible: bound it at this edge
            total += rate * left
            break
        total += rate * count
        left -= int(count)
    return float(total / B.size)


# -- noise estimators: the inputs of the model above ---------------------------------------------

def fit_noise_sigma(stack, shifts=None, mask=None, *, chunk_pixels: int = 65536) -> float:
    """Intensity noise per frame (input units) from the residuals of the N-step fit, N >= 4.

    Each pixel's N frames are fitted by ``A + B cos(phi - delta_n)`` (3 parameters); the residual
    sum of squares has ``N - 3`` degrees of freedom, so ``RSS / (N - 3)`` is an unbiased estimate
    of the noise variance there. The estimate is the root of its mean over the pixels of ``mask``
    (default: all) that no frame saturates (the integer dtype's maximum). It includes the
    quantisation noise (1/12 of a level squared) and any deviation from a sinusoid (a gamma
    curve), as the phase does.

    ARGUMENTS: stack (N, ...) frames (numpy); shifts (N,) rad (default ``2 pi n/N``); mask
    (...) bool. RETURNED VALUE: sigma (float, input units). UnwrapError for N < 4 or no pixel.
    """
    stack = np.asarray(stack)
    N = stack.shape[0]
    if N < 4:
        raise UnwrapError(f"{N} frames: the fit of A, B and phi leaves no residual to estimate the noise "
                          "from (needs N >= 4); give the noise level instead")
    delta = equal_shifts(N) if shifts is None else np.asarray(shifts, dtype=np.float64).reshape(-1)
    P = least_squares_weights(delta)
    M = np.stack([np.ones_like(delta), np.cos(delta), np.sin(delta)], axis=1)
    residual_maker = np.eye(N) - M @ P                      # I - hat matrix, (N, N)
    flat = stack.reshape(N, -1)
    keep = np.ones(flat.shape[1], bool) if mask is None else np.asarray(mask, bool).reshape(-1).copy()
    if np.issubdtype(flat.dtype, np.integer):
        keep &= ~(flat >= np.iinfo(flat.dtype).max).any(axis=0)
    total, count = 0.0, int(keep.sum())
    if count == 0:
        raise UnwrapError("no unsaturated pixel to estimate the noise from")
    for s in range(0, flat.shape[1], chunk_pixels):
        block = flat[:, s:s + chunk_pixels][:, keep[s:s + chunk_pixels]].astype(np.float64)
        total += float(np.sum((residual_maker @ block) ** 2))
    return math.sqrt(total / (count * (N - 3)))


def phase_noise_rad(phase, reference=None, erode: int = 3) -> float:
    """Phase noise (rad, 1 sigma) of a smooth absolute phase map, from second differences.

    For white noise of sigma s, ``p[i-1] - 2 p[i] + p[i+1]`` has standard deviation ``s sqrt 6``;
    its median absolute deviation (x 1.4826) is robust to the rim and to the odd outlier. Rows and
    columns are averaged; pixels within ``erode`` of the footprint's edge are left out. With a
    noise-free ``reference`` map of the same surface the estimator's own response to the surface's
    curvature is removed in quadrature.
    """
    from scipy.ndimage import binary_erosion

    def raw(p):
        p = np.asarray(p, dtype=np.float64)
        inner = binary_erosion(np.isfinite(p), iterations=erode)
        out = []
        for axis in (0, 1):
            d2 = np.roll(p, 1, axis) - 2 * p + np.roll(p, -1, axis)
            x = d2[inner & np.isfinite(d2)]
            if x.size < 50:
                raise UnwrapError(f"phase noise: only {x.size} interior pixels; the footprint is too small")
            out.append(1.4826 * np.median(np.abs(x - np.median(x))) / np.sqrt(6))
        return float(np.mean(out))

    s = raw(phase)
    if reference is not None:
        s = float(np.sqrt(max(s ** 2 - raw(reference) ** 2, 0.0)))
    return s


def plane_centre_dof(window: int = 5) -> float:
    """The factor that undoes a least-squares plane's degrees of freedom in the residual of the
    centre pixel of a full ``window`` x ``window`` box (odd, >= 3; the plane ``a + b x + c y`` in
    pixel offsets from the centre, every pixel of the box used).

    The residual ``r = (I - H) e`` of white noise of variance ``s^2`` has variance ``s^2 (1 - h)``
    at a pixel of leverage ``h``; at the centre of a symmetric box (x = y = 0) the columns x and y
    are orthogonal to the constant, so ``h = 1 / n`` with ``n = window^2``, and the factor is
    ``sqrt(n / (n - 1))`` (5 x 5: ``sqrt(25 / 24)``). Not ``sqrt(n / (n - 3))``: that undoes the
    fit in the mean square of all ``n`` residuals of the box, whose corner pixels have a larger
    leverage than the centre. Near an invalid pixel the box is not full and the leverage grows.
    """
    w = int(window)
    if w < 3 or w % 2 == 0:
        raise UnwrapError(f"window {window!r}: the plane's box must be odd and at least 3 pixels")
    n = w * w
    return math.sqrt(n / (n - 1.0))


def plane_residual_noise(residuals, modulation, steps: int, dof: float | None = None, *, window: int = 5) -> dict:
    """Phase and intensity noise from residuals of an absolute phase from a local plane fit.

    ``residuals`` (rad) of each pixel from the plane through its ``window`` x ``window`` neighbours,
    the pixel among them and all of them valid (interior pixels); ``dof`` undoes the fit's own
    degrees of freedom, by default :func:`plane_centre_dof` of ``window`` (5 x 5: ``sqrt(25 / 24)``,
    the centre pixel's leverage 1/25). The robust sigma is 1.4826 x the median absolute residual
    (rare 2 pi order errors are outliers it ignores). With the N-step noise gain
    (:func:`phase_sigma` inverted) each pixel's intensity noise is ``sigma_phase * B * sqrt(N / 2)``
    (full-scale units, ``modulation`` B), summarised by its median.

    RETURNED VALUE: {"sigma_phase_rad", "sigma_I", "modulation" (median B), "pixels"}.
    """
    dof = plane_centre_dof(window) if dof is None else float(dof)
    e = np.abs(np.asarray(residuals, dtype=np.float64).reshape(-1))
    B = np.asarray(modulation, dtype=np.float64).reshape(-1)
    sigma_phase = 1.4826 * np.median(e) * dof
    sigma_I = float(np.median(1.4826 * e * dof * B) * math.sqrt(steps / 2.0))
    return {"sigma_phase_rad": float(sigma_phase), "sigma_I": sigma_I, "modulation": float(np.median(B)),
            "pixels": int(e.size)}
