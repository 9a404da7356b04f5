"""Direct / global separation from the high-frequency steps, and the bound it puts on the bias of
the coarse phase (issue 21).

Light that reaches a camera pixel indirectly (interreflection between object and wall, within
concavities, subsurface scattering) left the projector from *other* columns. At a high fringe
frequency the indirect light integrates many periods and its sinusoid averages out: it adds to the
offset of the N-step fit but not to its modulation. That is the separation of S. K. Nayar, G.
Krishnan, M. D. Grossberg and R. Raskar, "Fast separation of direct and global components of a
scene using high frequency illumination", ACM SIGGRAPH 2006, as used by M. Gupta and S. K. Nayar,
"Micro phase shifting", CVPR 2012 (the formulas below are ours). Per pixel, with the projected
pattern ``a + b cos(.)`` (its offset / amplitude as the camera sees it, ``kappa = a / b``: the
projector's black level and response included), a direct reflectance ``d`` and a global kernel
``k(x')`` over projector columns ``x'``:

    A_h = black + d a + G,  G = a * integral k        (offset of the high frequency)
    B_h = d b                                         (modulation: the global sinusoid averaged out)

so the global / direct ratio of the offsets is

    rho = G / (d a) = (A_h - black) / (kappa B_h) - 1      (clipped at 0)

At the unit frequency the same global light carries a phasor ``b integral k(x') exp(i phi(x'))``
of amplitude at most ``b integral k = rho d b``, beside the direct phasor of amplitude ``d b``.
The coarse phase is the argument of their sum, so its bias is bounded by

    |d phi_1| <= asin(rho)   (rho < 1),   pi otherwise

(the extreme puts the global phasor at right angles to the sum). The direct amplitude is only
known to be at least ``B_h`` (defocus and the projector's and camera's blur lower the high
frequency's modulation, and then ``rho`` counts the lost modulation as global light), so when the
unit frequency's modulation ``B_1`` is given the bound also uses it: the global phasor's amplitude
is at most ``gamma = (A_h - black) / kappa - B_h`` and the observed unit phasor (length ``B_1``)
is direct + global, so ``sin |d phi_1| <= gamma / B_1`` whenever ``gamma < B_1`` (then the sum
cannot point backwards: a phasor of length > gamma cannot come from one of length < gamma turned
by more than pi / 2). Both hold; the bound is the smaller one,

    |d phi_1| <= min(asin(gamma / B_h), asin(gamma / B_1)) = asin(gamma / max(B_h, B_1)),

pi where ``gamma >= max(B_h, B_1)``: under pure blur (no global light, ``B_h = m B_1``) it is
``asin(1 - m)`` instead of ``asin(1 / m - 1)``. In fringes of the high frequency
of an MF pair (the prior ``r = (R Phi_1 - phi_h) / 2 pi``, ``R = f_h / f_1``) the bound is
``asin(rho) R / 2 pi``.

Assumptions, each on the conservative side (the bound gets larger, never smaller) unless said:
the global light's sinusoid averages out at the high frequency (not conservative where it does
not: a residual global phasor ``g_h`` in phase with the direct one raises ``B_h`` and lowers
``gamma`` by up to ``|g_h|``; the tests' scenes stay within 0.02 rad of the bound); the direct
modulation does not depend on the frequency (defocus or the camera's MTF lowering ``B_h`` only
raise ``rho``); ``black`` (camera black level + ambient light, the units of A) is
known or taken as 0 (ambient then counts as global: conservative with a given ``kappa``; with an
estimated one the unremoved black level raises the estimate as well, by ``black / B`` of the
pixels that set it, which scales ``rho`` by ``kappa / (kappa + black / B)`` at pixels as bright);
``kappa`` is the pattern's - when it is not
given it is estimated from the capture as a low percentile of ``A_h / B_h`` over well-modulated
pixels (:func:`pattern_offset_ratio`): global light only raises that ratio, so the estimate is
right where some pixels receive almost none, and **too high** (the bound optimistic) where every
pixel receives some (a scene in a concave corner). Known limit: the bound is loose - it assumes
the global light is fully coherent at the unit frequency, while light gathered from many columns
largely cancels; on the Cycles test set the bias is ~1/20 of it at the median (docs/learned.md).

SYNOPSIS

    >>> import numpy as np
    >>> from unwrap.global_light import bias_bound
    >>> B = np.full((2, 2), 40.0); A = np.array([[40.0, 48.0], [60.0, 100.0]])   # kappa = 1: A = B without global light
    >>> r = bias_bound(A, B, np.ones((2, 2), bool), kappa=1.0)
    >>> r.ratio.round(2).tolist()                      # global / direct
    [[0.0, 0.2], [0.5, 1.5]]
    >>> r.bound_rad.round(3).tolist()                  # asin(rho), pi where rho >= 1
    [[0.0, 0.201], [0.524, 3.142]]
    >>> float(r.fringes(1.0, 48.0)[0, 1].round(2))     # in fringes of f = 48 (MF 1 -> 48)
    1.54
    >>> B1 = np.full((2, 2), 80.0)                     # the unit modulation twice the high one: B_h is blurred
    >>> bias_bound(A, B, np.ones((2, 2), bool), kappa=1.0, modulation_low=B1).bound_rad.round(3).tolist()
    [[0.0, 0.1], [0.253, 0.848]]
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .errors import GlobalLightError

#: Percentile of ``A_h / B_h`` (over valid pixels with B_h at or above its median) that estimates
#: the pattern's offset / amplitude ratio when it is not given.
KAPPA_PERCENTILE = 1.0
#: Plausible range of that ratio: outside it the capture is not an N-step sinusoid as assumed
#: (saturation, a non-sinusoidal response, frames of different exposure).
KAPPA_RANGE = (0.3, 10.0)
MIN_PIXELS = 500


@dataclass
class GlobalBias:
    """Output of :func:`bias_bound` (camera image shape (H, W), float64; 0 at invalid pixels)."""
    ratio: np.ndarray          # rho = global / direct offset (>= 0)
    bound_rad: np.ndarray      # bound on |bias| of the coarse (unit) phase, rad, in [0, pi]
    kappa: float               # the pattern's offset / amplitude ratio used
    kappa_source: str          # "given" or "estimated (p1 of A/B)"
    notes: list = field(default_factory=list)

    def fringes(self, frequency_low: float, frequency_high: float) -> np.ndarray:
        """The bound in fringes of the high frequency of an MF pair (module docstring)."""
        if not (frequency_low > 0 and frequency_high >= frequency_low):
            raise GlobalLightError(f"frequencies ({frequency_low}, {frequency_high}): expected 0 < low <= high")
        return self.bound_rad * (float(frequency_high) / float(frequency_low)) / (2 * math.pi)


def pattern_offset_ratio(offset, modulation, valid, *, black: float = 0.0,
                         percentile: float = KAPPA_PERCENTILE) -> float:
    """The pattern's offset / amplitude ratio ``kappa`` as the camera sees it, estimated from a
    high-frequency N-step fit: the ``percentile`` of ``(A - black) / B`` over valid pixels whose B
    is at least the median B of the valid pixels (noise in A / B grows as B falls). Global and
    ambient light only raise the ratio, so a low percentile picks the pixels with the least of it
    (module docstring: too high where every pixel receives global light).

    Raises :class:`GlobalLightError` with fewer than :data:`MIN_PIXELS` such pixels or an
    estimate outside :data:`KAPPA_RANGE`."""
    A, B, v, fin = _check(offset, modulation, valid)
    v = v & fin & (B > 0)
    if v.sum() < MIN_PIXELS:
        raise GlobalLightError(f"too few valid modulated pixels ({int(v.sum())} < {MIN_PIXELS}) to estimate the "
                               "pattern's offset / amplitude ratio; give kappa")
    strong = v & (B >= np.median(B[v]))
    k = float(np.percentile((A[strong] - black) / B[strong], percentile))
    if not KAPPA_RANGE[0] <= k <= KAPPA_RANGE[1]:
        raise GlobalLightError(f"the pattern's offset / amplitude ratio estimated from the capture is {k:.3g}, "
                               f"outside {KAPPA_RANGE}: not an N-step sinusoid as assumed (saturation, a "
                               "non-sinusoidal response, a wrong black level?); give kappa")
    return k


def _check(offset, modulation, valid):
    """(A, B, valid, finite): float64 copies with non-finite values set to 0 and the mask of pixels
    where both were finite (a NaN / inf offset or modulation says nothing about global light: the
    callers give such valid pixels the bound pi, never 0)."""
    A, B = (np.asarray(a, dtype=np.float64) for a in (offset, modulation))
    v = np.asarray(valid, dtype=bool)
    if A.ndim != 2 or A.shape != B.shape or A.shape != v.shape:
        raise GlobalLightError(f"global light: expected one (H, W) shape for offset, modulation and valid, got "
                               f"{A.shape}, {B.shape}, {v.shape}")
    fin = np.isfinite(A) & np.isfinite(B)
    return np.where(fin, A, 0.0), np.where(fin, B, 0.0), v, fin


def bias_bound(offset_high, modulation_high, valid, *, kappa: float | None = None, black: float = 0.0,
               offset_low=None, modulation_low=None) -> GlobalBias:
    """Per-pixel global / direct ratio and the bound on the coarse phase's bias (module docstring).

    ARGUMENTS: offset_high ``A_h`` and modulation_high ``B_h`` (H, W) of the N-step fit of the
    highest frequency (any intensity unit, the same for both and for ``black``); valid (H, W)
    bool; ``kappa``: the pattern's offset / amplitude ratio (None: :func:`pattern_offset_ratio`);
    ``black``: camera black level + ambient (default 0: counted as global, conservative with a
    given ``kappa``, module docstring);
    ``offset_low``: optional ``A`` of the unit frequency - the global offset does not depend on the
    frequency, so its median ratio to ``A_h`` must be ~1; a note is added when it is off by more
    than 10 % (frames of different exposure or a response curve: the separation is then suspect);
    ``modulation_low``: optional ``B_1`` of the unit frequency (same units), which tightens the
    bound where the high frequency's modulation is blurred (module docstring).

    RETURNED VALUE: :class:`GlobalBias`."""
    A, B, v, fin = _check(offset_high, modulation_high, valid)
    if not (math.isfinite(black) and black >= 0):
        raise GlobalLightError(f"black level must be finite and >= 0, got {black!r}")
    notes = []
    if kappa is None:
        kappa, source = pattern_offset_ratio(A, B, v & fin, black=black), f"estimated (p{KAPPA_PERCENTILE:g} of A/B)"
    else:
        if not (math.isfinite(kappa) and KAPPA_RANGE[0] <= kappa <= KAPPA_RANGE[1]):
            raise GlobalLightError(f"kappa {kappa!r}: expected a finite offset / amplitude ratio in {KAPPA_RANGE}")
        source = "given"
    if offset_low is not None:
        A1, _, _, fin1 = _check(offset_low, modulation_high, valid)
        ok = v & fin1 & (A > 0)
        if ok.any():
            q = float(np.median(A1[ok] / A[ok]))
            if abs(q - 1.0) > 0.1:
                notes.append(f"median offset ratio unit / high frequency is {q:.3f}, not 1: the frequencies were "
                             "not captured alike; the separation is suspect")
    ok = v & fin & (B > 0)                                       # elsewhere in v: the bound pi
    rho = np.where(ok, np.maximum((A - black) / (kappa * np.where(ok, B, 1.0)) - 1.0, 0.0), 0.0)
    ref = B
    if modulation_low is not None:
        _, B1, _, _ = _check(np.zeros_like(B), modulation_low, valid)   # a non-finite B_1: B_h alone
        ref = np.maximum(B, B1)
    s = np.where(ok, rho * B / np.where(ok, ref, 1.0), 1.0)      # gamma / max(B_h, B_1)
    bound = np.where(s < 1.0, np.arcsin(np.minimum(s, 1.0)), math.pi)
    bound = np.where(v, np.where(ok, bound, math.pi), 0.0)
    return GlobalBias(rho, bound, float(kappa), source, notes)


__all__ = ["GlobalBias", "GlobalLightError", "KAPPA_PERCENTILE", "KAPPA_RANGE", "bias_bound", "pattern_offset_ratio"]
