"""Temporal phase unwrapping: multi-frequency (MF), multi-wavelength heterodyne (MW), number-theoretic (NT).

Conventions (DESIGN.md): a wrapped phase ``phi`` lies in (-pi, pi] (atan2); the absolute phase of
a pattern with ``f`` periods across the projector is ``Phi = 2*pi*f*u_p/W_p`` in [0, 2*pi*f); the
fringe order is ``k = (Phi - phi) / (2*pi)``, an integer in [0, round(f)] (k = f on the last half
period). The order is the prior rounded to the nearest integer, a prior within 1e-9 of a half
integer (a tie: the two phases disagree by exactly pi) going to the lower order on every path and
machine (:func:`unwrap._xp.round_order`). Every method returns :class:`Unwrapped` with the absolute phase of its highest
frequency, ``k``, a validity mask and the *physics prior*: the real-valued quantity inside
``Round[]`` of eqs. 7-9 of the paper's supplementary (for MF/MW the real fringe-order estimate,
for NT the real-valued residue ``(f1*phi2 - f2*phi1) / (2*pi)``).

MF, MW and the refinement step run on numpy arrays and torch tensors alike; NT's lookup is numpy.

SYNOPSIS

    >>> import numpy as np
    >>> from unwrap.patterns import absolute_phase
    >>> from unwrap.temporal import mf_unwrap
    >>> from unwrap._xp import wrap
    >>> u = np.arange(912.0)
    >>> phases = [wrap(absolute_phase(u, f, 912)) for f in (1, 8, 48)]
    >>> r = mf_unwrap(phases, (1, 8, 48))
    >>> bool(np.allclose(r.phase, absolute_phase(u, 48, 912))), int(r.order.max())
    (True, 48)
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from ._xp import TWO_PI, is_torch, namespace, round_order, wrap
from .errors import UnreliableFringesWarning, UnwrapError


@dataclass
class Unwrapped:
    """Absolute phase and fringe order of one orientation.

    - ``phase``: absolute phase of ``frequency`` (rad, float64), NaN where not ``valid``.
    - ``order``: fringe order k (int32), -1 where not ``valid``.
    - ``valid``: bool mask.
    - ``prior``: the real-valued quantity inside Round[] of the last step (float64, NaN where the
      input phases were invalid); ``Round(prior)`` gives the decision.
    - ``frequency``: periods across the pattern of ``phase``; ``method``: "mf", "mw", "nt", "gray".
    - ``levels``: per-step ``(frequency, prior, order)`` of intermediate steps (for diagnostics).
    """
    phase: object
    order: object
    valid: object
    prior: object
    frequency: float
    method: str
    levels: list = field(default_factory=list)


def _check_phase(phi, name, shape=None):
    if not is_torch(phi):
        phi = np.asarray(phi, dtype=np.float64)
    if shape is not None and tuple(phi.shape) != tuple(shape):
        raise UnwrapError(f"{name} has shape {tuple(phi.shape)}, expected {tuple(shape)} like the "
                          "first wrapped phase")
    return phi


def _check_frequencies(frequencies, n, what):
    f = np.asarray(frequencies, dtype=np.float64).reshape(-1)
    if f.size != n:
        raise UnwrapError(f"{n} wrapped phases but {f.size} {what} given: they must match")
    if not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise UnwrapError(f"{what} must be finite and > 0, got {f.tolist()}")
    return f


def _finite_mask(xp, arrays, valid):
    ok = None
    for a in arrays:
        m = xp.isfinite(a)
        ok = m if ok is None else ok & m
    if valid is not None:
        if not is_torch(ok):
            valid = np.asarray(valid, dtype=bool)
            if valid.shape != ok.shape:
                raise UnwrapError(f"valid mask has shape {valid.shape}, expected {ok.shape}")
        ok = ok & valid
    return ok


#: Without the pattern width, the 2*pi cut of a 1-period phase sits this fraction of the pattern
#: before coordinate 0 (half a pixel of a 1024-pixel projector).
DEFAULT_EDGE_FRACTION = 0.5 / 1024


def edge_fraction(width=None) -> float:
    """Fraction of the pattern before coordinate 0 where the 2*pi cut sits: half a pixel."""
    if width is None:
        return DEFAULT_EDGE_FRACTION
    if not width > 1:
        raise UnwrapError(f"width (projector pixels across the fringes) must be > 1, got {width}")
    return 0.5 / float(width)


def base_phase(phi, frequency: float = 1.0, width=None):
    """Absolute phase of a pattern with ``frequency <= 1`` period from its wrapped phase (rad).

    Pixel centres sit at 0 .. W-1, so the pattern covers [-0.5, W - 0.5) px; the 2*pi cut is put
    at u = -0.5 px (``width`` given) or at ``DEFAULT_EDGE_FRACTION`` of the pattern, and for
    f < 1 in the middle of the unused range. ``Phi`` lies in [c, c + 2*pi).
    """
    if frequency > 1.0 + 1e-12:
        raise UnwrapError(f"the lowest frequency must be <= 1 period across the pattern to be "
                          f"absolute, got {frequency}")
    xp = namespace(phi)
    c = base_cut(frequency, width)
    return xp.remainder(phi - c, TWO_PI) + c


def base_cut(frequency: float = 1.0, width=None) -> float:
    """The phase c (rad, <= 0) where :func:`base_phase` puts the 2*pi cut: Phi lies in [c, c + 2*pi)."""
    return min(-math.pi * (1.0 - frequency), -TWO_PI * frequency * edge_fraction(width))


def refine(Phi_coarse, ratio: float, phi):
    """One hierarchical step (eq. 7): ``prior = (ratio*Phi_coarse - phi)/(2 pi)``, k = Round(prior).

    ARGUMENTS: Phi_coarse = absolute phase of the coarser pattern (rad); ratio = f_fine/f_coarse;
    phi = wrapped phase of the finer pattern (rad). Arrays of one shape, numpy or torch.
    RETURNED VALUE: (prior float64, k float64 integer-valued, Phi_fine = phi + 2*pi*k).
    A step fails when |ratio*err(Phi_coarse) - err(phi)| > pi (see unwrap.reliability).
    """
    xp = namespace(Phi_coarse, phi)
    prior = (ratio * Phi_coarse - phi) / TWO_PI
    k = round_order(prior, xp)
    return prior, k, phi + TWO_PI * k


def constrain_to_pattern(xp, Phi, k, valid, frequency: float, width=None, wrap_orders=None):
    """The range constraint: an absolute phase must lie inside the pattern.

    The pattern covers projector coordinates [-0.5, W - 0.5) px, i.e. absolute phases
    [lo, lo + 2 pi f) with ``lo = -2 pi f * edge_fraction(width)`` (the base phase's cut). A pixel
    lit by the last half pixel of the pattern whose coarsest phase the noise carries across the
    cut decodes one ladder period too low (coordinate -0.5 px instead of W - 0.5). Where the
    decoder is periodic (``wrap_orders``: the number of orders by which a whole base period moves
    the result, an integer; None when the decode is not periodic, e.g. Gray code) such a phase is
    moved by that period when this lands inside the pattern; every phase still outside is invalid.
    Returns (Phi, k, valid); works on numpy arrays and torch tensors.
    """
    lo, hi = pattern_range(frequency, width)
    if wrap_orders:
        below = valid & (Phi < lo)
        above = valid & (Phi >= hi)
        Phi = xp.where(below, Phi + TWO_PI * wrap_orders, xp.where(above, Phi - TWO_PI * wrap_orders, Phi))
        k = xp.where(below, k + wrap_orders, xp.where(above, k - wrap_orders, k))
    return Phi, k, valid & (Phi >= lo) & (Phi < hi)


def pattern_range(frequency: float, width=None) -> tuple[float, float]:
    """Absolute phases (rad) of the pattern's extent [-0.5, W - 0.5) px: ``[lo, lo + 2 pi f)``,
    ``lo = -2 pi f * edge_fraction(width)`` (:func:`constrain_to_pattern`; the fused kernel uses
    the same two numbers)."""
    e = edge_fraction(width)
    return -TWO_PI * frequency * e, TWO_PI * frequency * (1.0 - e)


def ladder_wrap_orders(frequencies, base_frequency: float):
    """Orders by which one period of the base phase (frequency ``base_frequency`` <= 1) moves the
    final phase, when every frequency of the ladder is an integer multiple of the base's (the
    wrapped phases then repeat exactly); else None."""
    ratios = np.asarray(frequencies, dtype=np.float64) / float(base_frequency)
    if np.all(np.abs(ratios - np.round(ratios)) < 1e-9):
        return int(round(float(ratios.max())))
    return None


def finish_unwrapped(xp, Phi, k, prior, ok, frequency, method, levels, *, width=None,
                     wrap_orders=None) -> Unwrapped:
    """The :class:`Unwrapped` every method returns: orders outside [0, round(f)], pixels not
    ``ok`` and phases outside the pattern (:func:`constrain_to_pattern`, with ``width`` and
    ``wrap_orders``) are invalid (phase NaN, order -1); the prior is NaN where the inputs were
    invalid."""
    kmax = math.floor(frequency + 0.5)
    valid = ok & (k >= 0) & (k <= kmax)
    Phi, k, valid = constrain_to_pattern(xp, Phi, k, valid, frequency, width, wrap_orders)
    valid = valid & (k >= 0) & (k <= kmax)
    nan = math.nan
    phase = xp.where(valid, Phi, nan)
    order = xp.to_int32(xp.where(valid, k, -1.0))
    prior = xp.where(ok, prior, nan)
    return Unwrapped(phase, order, valid, prior, float(frequency), method, levels)


def _check_reliability(predicted: float, max_error_rate: float, on_unreliable: str, what: str):
    if predicted <= max_error_rate or on_unreliable == "ignore":
        return
    msg = (f"{what}: predicted fringe-order error rate {predicted:.3g} exceeds the limit "
           f"{max_error_rate:.3g} (see `calib plan-fringes`)")
    if on_unreliable == "raise":
        raise UnwrapError(msg)
    warnings.warn(msg, UnreliableFringesWarning, stacklevel=3)


def mf_unwrap(phases, frequencies, *, width=None, valid=None, phase_sigma=None, max_error_rate: float = 0.01,
              on_unreliable: str = "warn") -> Unwrapped:
    """Hierarchical multi-frequency unwrapping over any ladder (e.g. 1, 8, 48 or 1, 4, 16, 64).

    ARGUMENTS
    - phases: wrapped phases (rad, (-pi, pi]) one per frequency, equal shapes (numpy or torch).
    - frequencies: periods across the pattern, strictly increasing, the first <= 1 (absolute).
    - width: projector pixels across the fringes (optional; places the 2*pi cut of the base
      phase at u = -0.5 px).
    - valid: optional bool mask of usable pixels (e.g. the phase-shift masks combined).
    - phase_sigma: optional phase noise (rad; scalar or one per frequency). When given, the
      predicted error rate (unwrap.reliability) is checked against ``max_error_rate`` and
      ``on_unreliable`` ("warn", "raise", "ignore") decides what happens above it.
    RETURNED VALUE: :class:`Unwrapped` for the highest frequency.
    """
    if len(phases) < 2:
        raise UnwrapError(f"MF needs at least two wrapped phases, got {len(phases)}")
    f = check_mf_ladder(_check_frequencies(frequencies, len(phases), "frequencies"))
    shape = tuple(phases[0].shape)
    phis = [_check_phase(p, f"wrapped phase {i} (f={f[i]:g})", shape) for i, p in enumerate(phases)]
    if phase_sigma is not None:
        from .reliability import mf_error_rate
        sig = np.broadcast_to(np.asarray(phase_sigma, dtype=np.float64), f.shape)
        _check_reliability(mf_error_rate(f, sig), max_error_rate, on_unreliable,
                           f"MF ladder {f.tolist()} at phase noise {np.round(sig, 4).tolist()} rad")
    xp = namespace(*phis)
    ok = _finite_mask(xp, phis, valid)
    Phi = base_phase(phis[0], f[0], width)
    levels = []
    prior = k = None
    for i in range(1, len(f)):
        prior, k, Phi = refine(Phi, f[i] / f[i - 1], phis[i])
        levels.append((float(f[i]), prior, k))
    return finish_unwrapped(xp, Phi, k, prior, ok, f[-1], "mf", levels, width=width,
                            wrap_orders=ladder_wrap_orders(f, f[0]))


def check_mf_ladder(f) -> np.ndarray:
    """An MF ladder as float64: at least two frequencies, strictly increasing, the first <= 1
    period (absolute); UnwrapError otherwise (what :func:`mf_unwrap` and ``calib plan-fringes`` accept)."""
    f = np.asarray(f, dtype=np.float64).reshape(-1)
    if f.size < 2 or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise UnwrapError(f"MF needs at least two frequencies, finite and > 0, got {f.tolist()}")
    if np.any(np.diff(f) <= 0):
        raise UnwrapError(f"MF frequencies must increase strictly, got {f.tolist()}")
    if f[0] > 1.0 + 1e-12:
        raise UnwrapError(f"MF needs a lowest frequency <= 1 period (absolute), got {f[0]}: "
                          "add a 1-period pattern or use MW/NT/Gray code")
    return f


def check_mw_set(f):
    """A two- or three-wavelength MW set: (frequencies highest first, beats); UnwrapError when the
    wavelengths repeat or the final beat is not absolute (what :func:`mw_unwrap` accepts)."""
    f = np.asarray(f, dtype=np.float64).reshape(-1)
    n = f.size
    if n not in (2, 3):
        raise UnwrapError(f"MW takes two or three wavelengths, got {n}")
    if not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise UnwrapError(f"MW frequencies must be finite and > 0, got {f.tolist()}")
    if len(set(np.round(f, 12).tolist())) != n:
        raise UnwrapError(f"MW wavelengths must differ, got frequencies {f.tolist()}")
    f = np.sort(f)[::-1]
    beats = heterodyne_frequencies(f)
    if beats[-1] > 1.0 + 1e-9:
        raise UnwrapError(f"MW frequencies {f.tolist()}: the final beat frequency is {beats[-1]:g} "
                          "periods > 1, so the heterodyne phase is not absolute; choose wavelengths "
                          "whose beat spans the whole pattern")
    if n == 3 and (beats[0] <= 0 or beats[1] <= 0 or beats[2] <= 0):
        raise UnwrapError(f"MW frequencies {f.tolist()}: beats {beats} must be > 0 "
                          "(f1 - f2 must differ from f2 - f3)")
    return f, beats


def check_nt_pair(f) -> tuple[int, int]:
    """Two different coprime integer frequencies (what :func:`nt_unwrap` accepts), as ints."""
    f = np.asarray(f, dtype=np.float64).reshape(-1)
    if f.size != 2:
        raise UnwrapError(f"NT takes two frequencies, got {f.size}")
    if not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise UnwrapError(f"NT frequencies must be finite and > 0, got {f.tolist()}")
    if np.any(f != np.round(f)):
        raise UnwrapError(f"NT frequencies must be integers (periods across the pattern), got {f.tolist()}")
    f1, f2 = (int(v) for v in f)
    if f1 == f2:
        raise UnwrapError(f"NT frequencies must differ, got {f1} and {f2}")
    _check_coprime(f1, f2)
    return f1, f2


def _check_coprime(f1: int, f2: int) -> None:
    g = math.gcd(f1, f2)
    if g != 1:
        raise UnwrapError(f"NT frequencies {f1} and {f2} share the factor {g}: the pair repeats "
                          f"{g} times across the pattern, so k is ambiguous; choose coprime "
                          f"frequencies (e.g. {f1} and {f2 + 1 if math.gcd(f1, f2 + 1) == 1 else f2 - 1})")


def _frequencies_from(frequencies, pitches, width, n):
    if (frequencies is None) == (pitches is None):
        raise UnwrapError("give either frequencies (periods across the pattern) or pitches "
                          "(projector pixels per period, with width)")
    if pitches is not None:
        p = _check_frequencies(pitches, n, "pitches")
        if width is None or not width > 0:
            raise UnwrapError("pitches need the pattern width (projector pixels across the fringes)")
        return float(width) / p
    return _check_frequencies(frequencies, n, "frequencies")


def _check_beat_in_field(method: str, f, width) -> None:
    """Refuse a pair whose beat wraps inside the ``width``-px pattern, naming its common window
    (:mod:`unwrap.common_window`); no-op without a width or for other than two frequencies."""
    if width is None or len(f) != 2 or not width > 1:
        return
    lo, hi = sorted(float(v) for v in f)
    if hi - lo > 1.0 + 1e-9:
        from .common_window import beat_window_message
        raise UnwrapError(beat_window_message(method, lo, hi, float(width)))


def heterodyne_frequencies(frequencies):
    """The equivalent (beat) frequencies of 2 or 3 wavelengths, highest first.

    Two: ``[f1 - f2]``; three: ``[f1 - f2, f2 - f3, |(f1 - f2) - (f2 - f3)|]``.
    """
    f = np.sort(np.asarray(frequencies, dtype=np.float64))[::-1]
    if len(f) == 2:
        return [f[0] - f[1]]
    f12, f23 = f[0] - f[1], f[1] - f[2]
    return [f12, f23, abs(f12 - f23)]


def mw_unwrap(phases, frequencies=None, *, pitches=None, width=None, valid=None,
              phase_sigma=None, max_error_rate: float = 0.01,
              on_unreliable: str = "warn") -> Unwrapped:
    """Multi-wavelength heterodyne unwrapping with two or three wavelengths (eq. 8).

    ARGUMENTS
    - phases: 2 or 3 wrapped phases (rad), any order.
    - frequencies (periods across the pattern) or pitches (projector pixels per period; need not
      divide ``width``) + width (projector pixels across the fringes).
    - The final beat frequency (f1 - f2 for two, |f12 - f23| for three) must be <= 1 period.
    - valid, phase_sigma, max_error_rate, on_unreliable: as :func:`mf_unwrap`; ``width`` also
      places the 2*pi cut of the beat phase.
    RETURNED VALUE: :class:`Unwrapped` for the highest frequency f1.
    """
    n = len(phases)
    if n not in (2, 3):
        raise UnwrapError(f"MW takes two or three wavelengths, got {n}")
    f = _frequencies_from(frequencies, pitches, width, n)
    _check_beat_in_field("mw", f, width)
    order = np.argsort(-f, kind="stable")
    f, beats = check_mw_set(f)
    shape = tuple(phases[0].shape)
    phis = [_check_phase(phases[i], f"wrapped phase {i}", shape) for i in order]
    if phase_sigma is not None:
        from .reliability import mw_error_rate
        sig = np.broadcast_to(np.asarray(phase_sigma, dtype=np.float64), f.shape)
        _check_reliability(mw_error_rate(f, sig), max_error_rate, on_unreliable,
                           f"MW set {f.tolist()} at phase noise {np.round(sig, 4).tolist()} rad")
    xp = namespace(*phis)
    ok = _finite_mask(xp, phis, valid)
    levels = []
    if n == 2:
        Phi_eq = base_phase(wrap(phis[0] - phis[1], xp), beats[0], width)
        f_eq = beats[0]
    else:
        f12, f23, f123 = beats
        phi12 = wrap(phis[0] - phis[1], xp)
        phi23 = wrap(phis[1] - phis[2], xp)
        sign = 1.0 if f12 > f23 else -1.0
        Phi123 = base_phase(wrap(sign * (phi12 - phi23), xp), f123, width)
        prior12, k12, Phi_eq = refine(Phi123, f12 / f123, phi12)
        levels.append((float(f12), prior12, k12))
        f_eq = f12
    prior, k, Phi = refine(Phi_eq, f[0] / f_eq, phis[0])
    levels.append((float(f[0]), prior, k))
    return finish_unwrapped(xp, Phi, k, prior, ok, f[0], "mw", levels, width=width,
                            wrap_orders=ladder_wrap_orders(list(f) + list(beats), beats[-1]))


@lru_cache(maxsize=128)
def nt_lookup_table(f1: int, f2: int):
    """Lookup table of number-theoretic unwrapping for a coprime pair, built once per pair.

    For the integer residue ``m = f2*k1 - f1*k2`` (``Round[(f1*phi2 - f2*phi1)/(2 pi)]``, eq. 9)
    ``table[m + offset]`` is ``k1 mod f1``. Returns (table int32 read-only, offset).
    """
    _check_coprime(f1, f2)
    inv = pow(f2, -1, f1)
    offset = f1 * f2 + f1 + f2
    m = np.arange(-offset, offset + 1, dtype=np.int64)
    table = ((m * inv) % f1).astype(np.int32)
    table.setflags(write=False)
    return table, offset


def nt_unwrap(phases, frequencies, *, width=None, valid=None, phase_sigma=None, max_error_rate: float = 0.01,
              on_unreliable: str = "warn") -> Unwrapped:
    """Number-theoretic unwrapping of two coprime integer frequencies (eq. 9).

    ARGUMENTS: phases = two wrapped phases (rad); frequencies = two coprime integers (periods
    across the pattern), e.g. (47, 48) or (95, 96); valid, phase_sigma, ...: as :func:`mf_unwrap`.
    RETURNED VALUE: :class:`Unwrapped` for the higher frequency; ``prior`` is the real residue
    ``(f1*phi2 - f2*phi1)/(2 pi)`` (integer when noise-free). numpy only.
    """
    if len(phases) != 2:
        raise UnwrapError(f"NT takes two wrapped phases, got {len(phases)}")
    f = _check_frequencies(frequencies, 2, "frequencies")
    if np.any(f != np.round(f)):
        _check_beat_in_field("nt", f, width)
    f1, f2 = check_nt_pair(f)
    table, offset = nt_lookup_table(f1, f2)
    if any(is_torch(p) for p in phases):
        raise UnwrapError("nt_unwrap works on numpy arrays (convert tensors with .numpy())")
    shape = np.shape(phases[0])
    phi1 = _check_phase(phases[0], "wrapped phase 0", shape)
    phi2 = _check_phase(phases[1], "wrapped phase 1", shape)
    if phase_sigma is not None:
        from .reliability import nt_error_rate
        sig = np.broadcast_to(np.asarray(phase_sigma, dtype=np.float64), (2,))
        _check_reliability(nt_error_rate((f1, f2), sig), max_error_rate, on_unreliable,
                           f"NT pair ({f1}, {f2}) at phase noise {np.round(sig, 4).tolist()} rad")
    ok = _finite_mask(namespace(phi1), (phi1, phi2), valid)
    prior = (f1 * phi2 - f2 * phi1) / TWO_PI
    m = round_order(np.where(ok, prior, 0.0)).astype(np.int64)
    k1 = table[np.clip(m + offset, 0, table.size - 1)].astype(np.int64)
    # k1 = 0 and k1 = f1 share the residue: below u = -0.5 px it is the last half period (k1 = f1)
    k1 = np.where((k1 == 0) & (phi1 < -TWO_PI * f1 * edge_fraction(width)), f1, k1)
    k2_num = f2 * k1 - m
    k2 = k2_num // f1
    ok = ok & (np.abs(m) <= offset)
    if f2 > f1:
        Phi, k, fout = phi2 + TWO_PI * k2, k2, f2
    else:
        Phi, k, fout = phi1 + TWO_PI * k1, k1, f1
    levels = [(float(f1), None, k1), (float(f2), None, k2)]
    return finish_unwrapped(namespace(Phi), Phi, k.astype(np.float64), prior, ok & (k1 <= f1) & (k2 >= 0) & (k2 <= f2),
                            fout, "nt", levels, width=width, wrap_orders=int(fout))


def decode_pair(method: str, phi_lo, phi_hi, f_lo: float, f_hi: float, width: float, valid):
    """The traditional decode of one (low, high) pair (``unwrap.methods.PAIR_METHODS``) on wrapped
    phases (rad): (prior float64 (H,W), order int64 (H,W) -1 invalid, valid bool); ``order`` is
    the method's order of the high frequency clipped to [0, round(f_hi)]. The learned network's
    input and the dataset reader's ``order_traditional``."""
    if method == "mf":
        r = mf_unwrap([phi_lo, phi_hi], (f_lo, f_hi), width=width, valid=valid)
        k = r.levels[-1][2]
    elif method == "mw":
        r = mw_unwrap([phi_lo, phi_hi], (f_lo, f_hi), width=width, valid=valid)
        k = r.levels[-1][2]
    else:
        r = nt_unwrap([phi_lo, phi_hi], (f_lo, f_hi), width=width, valid=valid)
        k = r.levels[1][2]
    prior = np.asarray(r.prior, dtype=np.float64)
    ok = valid & np.isfinite(prior)
    kmax = math.floor(f_hi + 0.5)
    order = np.where(ok, np.clip(np.nan_to_num(np.asarray(k, dtype=np.float64)), 0, kmax), -1).astype(np.int64)
    return np.where(ok, prior, 0.0), order, ok
