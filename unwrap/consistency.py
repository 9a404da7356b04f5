"""Is a decode consistent with its frames? The fringe-order priors of a right decode cluster near integers.

Every rounding step ``k = Round(prior)`` of MF, MW and NT (eqs. 7-9 of the supplementary) has a
real-valued prior whose distance to the nearest integer is the step's disagreement between the
coarse and the fine phase, in periods. With the right frequency ladder and phase-shift
convention that disagreement is noise (hundredths of a period on usable pixels), so nearly every
kept pixel lies within 1/4 of an integer. Frames decoded with the wrong convention (written as
``A + B cos(Phi + delta_n)`` with a pi offset, as another lab's captures were) or the wrong
frequencies spread the fractional part uniformly (about half the pixels within 1/4) or put it
at half integers (none): the orders are then wrong nearly everywhere although most pixels are
"valid". :func:`prior_check` measures the fraction per step, :func:`check_priors` refuses a
decode below :data:`MIN_NEAR_FRACTION` and names the likely causes.

A shift sign that is wrong alone is not visible here: it decodes ``2 pi f - Phi``, the mirror
image of the pattern (projector coordinate ``W - u``), which is as consistent as the truth.
Gray-code decoders choose their code by the phase itself (their prior is always near an
integer), so they are not checked.

SYNOPSIS

    >>> import numpy as np
    >>> from unwrap.consistency import prior_check
    >>> from unwrap.patterns import absolute_phase
    >>> from unwrap.temporal import mf_unwrap
    >>> from unwrap._xp import wrap
    >>> u = np.arange(912.0)
    >>> right = [wrap(absolute_phase(u, f, 912)) for f in (1, 8, 48)]
    >>> prior_check(mf_unwrap(right, (1, 8, 48)))
    [(8.0, 1.0), (48.0, 1.0)]
    >>> offset = [wrap(p + np.pi) for p in right]          # every pattern starts dark: a pi offset
    >>> [(f, round(x, 2)) for f, x in prior_check(mf_unwrap(offset, (1, 8, 48)))]
    [(8.0, 0.0), (48.0, 0.0)]
"""
from __future__ import annotations

import numpy as np

from .errors import UnwrapError

#: A prior within this distance (periods) of an integer counts as near.
NEAR = 0.25
#: Smallest fraction of kept pixels with a near prior that a decode may have at every step. A
#: uniform spread gives 0.5, half-integer priors 0; right decodes give 1.0 on rendered 12-step
#: sessions and 0.83-0.98 on the SLStudio example's real 3-step captures (ratio 16 in one step,
#: docs/unwrap.md). 0.65 is what Gaussian prior noise with about 6 % wrong orders gives.
MIN_NEAR_FRACTION = 0.65


def prior_check(result) -> list:
    """(frequency, fraction of the valid pixels whose prior lies within :data:`NEAR` of an
    integer) for every rounding step of an :class:`unwrap.temporal.Unwrapped` that recorded its
    steps' priors (MF, MW), else for its final prior (NT); [] when nothing is valid."""
    valid = np.asarray(result.valid, dtype=bool)
    if not valid.any():
        return []
    steps = [(f, prior) for f, prior, _ in result.levels if prior is not None]
    if not steps:
        steps = [(result.frequency, result.prior)]
    out = []
    for frequency, prior in steps:
        p = np.asarray(prior, dtype=np.float64)[valid]
        near = np.abs(p - np.round(p)) <= NEAR
        out.append((float(frequency), float(np.mean(near))))
    return out


def check_priors(checks, where: str) -> None:
    """Refuse (UnwrapError) when a step of ``checks`` (:func:`prior_check`) has fewer than
    :data:`MIN_NEAR_FRACTION` of its pixels near an integer; ``where`` names the decode."""
    bad = [(f, x) for f, x in checks if x < MIN_NEAR_FRACTION]
    if not bad:
        return
    steps = ", ".join(f"step to f = {f:g}: {100 * x:.0f} %" for f, x in bad)
    halves = all(x < 0.25 for _, x in bad)
    cause = ("the priors sit at half integers: a phase offset of pi between frequencies (frames written as "
             "A + B cos(Phi + pi ...), i.e. capture.toml [pattern] phase_offset = 3.141592653589793, often "
             "with shift_sign = -1 for A + B cos(Phi + 2 pi n/N))" if halves else
             "the priors are spread as if random: the frequency ladder does not match the frames (wrong "
             "[pattern] frequencies or their order), or the phase-shift convention does ([pattern] "
             "shift_sign = -1 for A + B cos(Phi + 2 pi n/N), phase_offset, or explicit shifts)")
    raise UnwrapError(f"{where}: the fringe orders are not consistent with the frames ({steps} of the kept "
                      f"pixels have a prior within {NEAR} of an integer; a right decode gives nearly 100 %, "
                      f"random orders 50 %). Likely cause: {cause}. To decode anyway, turn the check off "
                      "(--no-prior-check, check_prior=False)")
