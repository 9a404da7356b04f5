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
pattern); :func:`monte_carlo_error_rate` simulates real intensity stacks the same way.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.special import erf

from .errors import UnwrapError

_GRID = 4001


def phase_sigma(sigma, steps: int, B) -> float:
    """Phase noise (rad) of N-step least squares: ``sqrt(2 sigma^2 / (N B^2))`` (high SNR)."""
    if steps < 3 or not B > 0 or sigma < 0:
        raise UnwrapError(f"phase_sigma needs steps >= 3, B > 0, sigma >= 0; got {steps}, {B}, {sigma}")
    return math.sqrt(2.0 * sigma ** 2 / (steps * B ** 2))


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


class _Dist:
    """Density and CDF of one phase error on a grid over its support."""

    def __init__(self, sigma_phi: float):
        L = min(math.pi, 14.0 * sigma_phi)
        self.x = np.linspace(-L, L, _GRID)
        p = phase_error_pdf(self.x, sigma_phi)
        cdf = np.concatenate([[0.0], np.cumsum(0.5 * (p[1:] + p[:-1]) * np.diff(self.x))])
        total = cdf[-1]
        self.p = p / total
        self.cdf = cdf / total

    def F(self, v):
        return np.interp(v, self.x, self.cdf, left=0.0, right=1.0)

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
    d_prev = _Dist(s[0])
    g_x, g_p = d_prev.x, d_prev.p  # density of the current absolute-phase error, restricted to "no failure so far"
    for i in range(1, f.size):
        r = f[i] / f[i - 1]
        d = _Dist(s[i])
        G = np.concatenate([[0.0], np.cumsum(0.5 * (g_p[1:] + g_p[:-1]) * np.diff(g_x))])
        hi = np.interp((d.x + math.pi) / r, g_x, G, left=0.0, right=G[-1])
        lo = np.interp((d.x - math.pi) / r, g_x, G, left=0.0, right=G[-1])
        g_x, g_p = d.x, d.p * (hi - lo)
    return float(min(1.0, max(0.0, 1.0 - np.trapz(g_p, g_x))))


def _two_error_fail(a: float, b: float, d_a: _Dist, d_b: _Dist) -> float:
    """P(|a e_a - b e_b| > pi) for independent e_a, e_b."""
    ok = d_b.F((math.pi + a * d_a.x) / b) - d_b.F((-math.pi + a * d_a.x) / b)
    return float(min(1.0, max(0.0, 1.0 - d_a.integrate(ok))))


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
    total = 0.0
    nodes, weights = np.polynomial.legendre.leggauss(96)
    ok_e2 = np.empty_like(d[1].x)
    for j, e2 in enumerate(d[1].x):
        # step B ok: |(f2/f12) e1 - (f1/f12) e2| <= pi  ->  e1 in [lo, hi]
        lo = ((f[0] / f12) * e2 - math.pi) / (f[1] / f12)
        hi = ((f[0] / f12) * e2 + math.pi) / (f[1] / f12)
        lo, hi = max(lo, d[0].x[0]), min(hi, d[0].x[-1])
        if hi <= lo:
            ok_e2[j] = 0.0
            continue
        e1 = 0.5 * (hi - lo) * nodes + 0.5 * (hi + lo)
        w = 0.5 * (hi - lo) * weights
        p1 = np.interp(e1, d[0].x, d[0].p)
        # step A ok: |c * sign*(e12 - e23) - e12| <= pi, e12 = e1 - e2, e23 = e2 - e3 (linear in e3)
        e12 = e1 - e2
        base = c * sign * (e12 - e2) - e12  # coefficient of e3 is c*sign
        cs = c * sign
        b1 = (math.pi - base) / cs
        b2 = (-math.pi - base) / cs
        pA = np.abs(d[2].F(np.maximum(b1, b2)) - d[2].F(np.minimum(b1, b2)))
        ok_e2[j] = float(np.sum(w * p1 * pA))
    total = d[1].integrate(ok_e2)
    return float(min(1.0, max(0.0, 1.0 - total)))


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


def monte_carlo_error_rate(method: str, frequencies, *, steps: int, sigma: float, B: float = 1.0,
                           n_pixels: int = 1_000_000, width: int = 912, seed: int = 0,
                           chunk: int = 500_000) -> tuple[float, int]:
    """Fringe-order error rate of simulated noisy N-step stacks (interior pixels u in [W/4, 3W/4]).

    Builds frames with :func:`unwrap.patterns.fringe_intensity` plus Gaussian noise ``sigma``,
    runs :func:`unwrap.phase_shift.wrapped_phase` and the unwrapping method, and counts pixels
    whose k differs from the truth. Returns (rate, n_errors).
    """
    from .graycode import complementary_gray_unwrap
    from .patterns import absolute_phase, fringe_intensity
    from .phase_shift import wrapped_phase
    from .temporal import mf_unwrap, mw_unwrap, nt_unwrap

    rng = np.random.default_rng(seed)
    f = [float(v) for v in frequencies]
    errors = 0
    done = 0
    while done < n_pixels:
        n = min(chunk, n_pixels - done)
        u = rng.uniform(0.25 * width, 0.75 * width, n)
        phis = []
        for fi in f:
            Phi = absolute_phase(u, fi, width)
            stack = np.stack([fringe_intensity(Phi, j, steps, A=2.0 * B, B=B) for j in range(steps)])
            stack += rng.normal(0.0, sigma, stack.shape)
            phis.append(wrapped_phase(stack, saturation=None).phase)
        f_hi = max(f)
        Phi_hi = absolute_phase(u, f_hi, width)
        if method == "cgray":
            K1 = np.floor(u * f_hi / width)
            K2 = np.floor(u * f_hi / width + 0.5)
            r = complementary_gray_unwrap(phis[0], K1, K2, f_hi)
        elif method == "mf":
            r = mf_unwrap(phis, f, width=width, on_unreliable="ignore")
        elif method == "mw":
            r = mw_unwrap(phis, f, width=width, on_unreliable="ignore")
        elif method == "nt":
            r = nt_unwrap(phis, f, width=width, on_unreliable="ignore")
        else:
            raise UnwrapError(f"unknown method {method!r}")
        # truth from the noise-free phase; a pixel is wrong when its absolute phase is off by a period
        wrong = ~r.valid | (np.abs(r.phase - Phi_hi) > math.pi)
        errors += int(np.count_nonzero(wrong))
        done += n
    return errors / n_pixels, errors
