"""Monte Carlo check of the predicted fringe-order error rates (:mod:`unwrap.reliability`):
simulated noisy N-step stacks, decoded and unwrapped, errors counted against the truth."""
from __future__ import annotations

import math

import numpy as np

from .errors import UnwrapError
from .graycode import complementary_gray_unwrap
from .patterns import absolute_phase, fringe_intensity
from .phase_shift import wrapped_phase
from .temporal import mf_unwrap, mw_unwrap, nt_unwrap


def monte_carlo_error_rate(method: str, frequencies, *, steps: int, sigma: float, B: float = 1.0,
                           n_pixels: int = 1_000_000, width: int = 912, seed: int = 0,
                           chunk: int = 500_000) -> tuple[float, int]:
    """Fringe-order error rate of simulated noisy N-step stacks (interior pixels u in [W/4, 3W/4]).

    Builds frames with :func:`unwrap.patterns.fringe_intensity` plus Gaussian noise ``sigma``,
    runs :func:`unwrap.phase_shift.wrapped_phase` and the unwrapping method, and counts pixels
    whose k differs from the truth. Returns (rate, n_errors).
    """
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
