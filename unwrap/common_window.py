"""A two-frequency pair whose beat is shorter than the pattern: its common window, and the refusal
that names it (issue 21, item 5).

Two fringe pitches ``p_lo > p_hi`` (projector px per period; frequencies ``f = W / p`` over a
pattern of ``W`` px) repeat together every beat period ``L = W / (f_hi - f_lo) = p_lo p_hi /
(p_lo - p_hi)`` px (45/48 px: 720; 42/48: 336; 42/45: 630). Over a field wider than ``L`` the beat
wraps inside the field and no decode can tell ``u`` from ``u + L``: MW's heterodyne phase is not
absolute and NT's frequencies are not whole numbers. Such a pair is decoded **on its common
window**: declare the pattern ``L`` px wide (``[projector] size`` across the fringes) with the
frequencies ``L / p_lo``, ``L / p_hi`` (15 and 16 for 45/48 px); the orders and projector
coordinates are then exact modulo ``L``, i.e. within the window. The decoders refuse the pair on
the whole field with :func:`beat_window_message` rather than decode beyond one beat.

    >>> w = common_window(912 / 48, 912 / 45, 912)
    >>> round(w["window_px"], 6), [round(f, 6) for f in w["frequencies"]], w["whole"]
    (720.0, [15.0, 16.0], True)
"""
from __future__ import annotations


def common_window(f_lo: float, f_hi: float, width: float) -> dict:
    """The pair's beat period and frequencies over it: {"window_px": L, "pitches_px": (p_lo, p_hi),
    "frequencies": (L / p_lo, L / p_hi), "whole": both frequencies whole (within 1e-6)}.
    ``f_lo < f_hi``: periods across ``width`` px."""
    f_lo, f_hi, width = float(f_lo), float(f_hi), float(width)
    L = width / (f_hi - f_lo)
    p_lo, p_hi = width / f_lo, width / f_hi
    fr = (L / p_lo, L / p_hi)
    return {"window_px": L, "pitches_px": (p_lo, p_hi), "frequencies": fr,
            "whole": all(abs(f - round(f)) < 1e-6 for f in fr)}


def beat_window_message(method: str, f_lo: float, f_hi: float, width: float) -> str:
    """Why a pair whose beat wraps inside the ``width``-px pattern is refused, and how to declare
    it on its common window."""
    w = common_window(f_lo, f_hi, width)
    p_lo, p_hi = w["pitches_px"]
    msg = (f"{method.upper()} pair of {f_lo:g} and {f_hi:g} periods over {width:g} px (pitches {p_lo:.4g} and "
           f"{p_hi:.4g} px): the beat frequency is {f_hi - f_lo:.3g} periods > 1, i.e. the beat period "
           f"{w['window_px']:.4g} px is shorter than the pattern's {width:g} px, so the beat wraps inside the field "
           "and the order is ambiguous beyond one beat")
    if w["whole"]:
        a, b = (int(round(f)) for f in w["frequencies"])
        msg += (f"; declare the pair on its common window: a pattern {w['window_px']:.4g} px wide ([projector] size "
                f"across the fringes) with frequencies {a} and {b} (the decode is then exact modulo "
                f"{w['window_px']:.4g} px; docs/unwrap.md)")
    else:
        msg += "; choose pitches whose beat spans the whole pattern, or a third frequency"
    return msg


def pair_wrap_orders(method: str, f_lo: float, f_hi: float):
    """Orders of the high frequency per period of the coarse (beat) phase, an int, for MW / NT
    pairs whose ratio ``f_hi / (f_hi - f_lo)`` is whole (within 1e-9; 16 for 15 / 16, 48 for
    47 / 48): the period by which a decode of the pair repeats, by which a correction or a phase
    outside the pattern moves (:func:`unwrap.temporal.constrain_to_pattern`). None otherwise (MF,
    or a ratio that is not whole)."""
    if method == "mf" or not f_hi > f_lo:
        return None
    r = float(f_hi) / (float(f_hi) - float(f_lo))
    return int(round(r)) if abs(r - round(r)) < 1e-9 else None
