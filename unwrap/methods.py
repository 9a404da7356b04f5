"""The temporal unwrapping methods: one enumeration and one rule for the frequency pair a method
decodes (the learned network, the dataset reader, the evaluation and the capture path use it).

- :data:`METHODS`: every method ``calib unwrap`` decodes; :data:`PAIR_METHODS`: those decoding a
  (low, high) frequency pair, which the learned network learns (``mf``: the unit frequency and
  the highest; ``mw`` / ``nt``: the two highest).

SYNOPSIS

    >>> pair_indices("mf", 3), pair_indices("nt", 3), pair_at("mw", 48)
    ((0, 2), (1, 2), (47.0, 48.0))
    >>> check_pair("mw", 40, 48)
    Traceback (most recent call last):
    ...
    unwrap.errors.UnwrapError: mw pair (40, 48): the beat 8 periods exceeds 1, so it is not absolute
"""
from __future__ import annotations

import math

from .errors import UnwrapError

METHODS = ("mf", "mw", "nt", "gray")
PAIR_METHODS = ("mf", "mw", "nt")


def check_method(method: str, allowed=PAIR_METHODS, error=UnwrapError) -> str:
    """``method`` if it is one of ``allowed``, else ``error`` naming them."""
    if method not in allowed:
        raise error(f"method {method!r}: expected one of {tuple(allowed)}")
    return method


def check_pair(method: str, f_lo: float, f_hi: float, error=UnwrapError) -> None:
    """Refuse a (method, (low, high)) pair its decoder cannot use: MF needs the unit frequency,
    MW a beat of at most one period, NT coprime whole numbers."""
    check_method(method, PAIR_METHODS, error)
    if not f_hi > f_lo > 0:
        raise error(f"frequencies ({f_lo:g}, {f_hi:g}): expected (low, high) with high > low > 0")
    if method == "mf" and f_lo > 1 + 1e-12:
        raise error(f"mf needs a unit frequency (<= 1 period) as the low one, got {f_lo:g}")
    if method == "mw" and f_hi - f_lo > 1 + 1e-9:
        raise error(f"mw pair ({f_lo:g}, {f_hi:g}): the beat {f_hi - f_lo:g} periods exceeds 1, so it "
                    "is not absolute")
    if method == "nt" and (f_lo != int(f_lo) or f_hi != int(f_hi) or math.gcd(int(f_lo), int(f_hi)) != 1):
        raise error(f"nt pair ({f_lo:g}, {f_hi:g}): expected coprime whole numbers")


def pair_indices(method: str, n: int, error=UnwrapError) -> tuple[int, int]:
    """Indices (low, high) into ``n`` sorted frequencies of the pair ``method`` decodes."""
    check_method(method, PAIR_METHODS, error)
    if n < 2:
        raise error(f"method {method!r} decodes a pair of fringe frequencies; the capture has {n}")
    return (0, n - 1) if method == "mf" else (n - 2, n - 1)


def pair_at(method: str, f: float, error=UnwrapError) -> tuple[float, float]:
    """The (low, high) pair of ``method`` whose high frequency is ``f``: (1, f) for MF,
    (f - 1, f) for MW and NT (the pairs the paper's tables S5 / S6 score)."""
    check_method(method, PAIR_METHODS, error)
    return (1.0, float(f)) if method == "mf" else (float(f) - 1.0, float(f))


def coarse_ratio(method: str, f_lo: float, f_hi: float) -> float:
    """Noise gain of the pair's prior: ``f_hi`` over the coarse (unit or beat) frequency."""
    return f_hi / f_lo if method == "mf" else f_hi / (f_hi - f_lo)
