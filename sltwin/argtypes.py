"""argparse types of the ``calib`` options: numbers checked where they are parsed, so that a
negative count or a zero threshold is refused by the option's name (exit 2, argparse's usage
line) instead of failing later inside the computation (a ZeroDivisionError, an empty table).

    >>> import argparse
    >>> from sltwin.argtypes import positive_float
    >>> positive_float("2.5")
    2.5
    >>> positive_float("-1")
    Traceback (most recent call last):
    ...
    argparse.ArgumentTypeError: expected a finite number > 0, got -1
"""
from __future__ import annotations

import argparse
import math


def _checked(kind, ok, what: str):
    """An argparse type: ``text`` as ``kind`` (finite, for floats) for which ``ok(value)`` holds;
    else ``ArgumentTypeError("expected WHAT, got TEXT")``, which argparse prints after the option."""
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if (kind is float and not math.isfinite(value)) or not ok(value):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text}")
        return value
    parse.__doc__ = f"argparse type: {what}."
    return parse


positive_int = _checked(int, lambda v: v >= 1, "a whole number >= 1")
positive_float = _checked(float, lambda v: v > 0, "a finite number > 0")
nonnegative_float = _checked(float, lambda v: v >= 0, "a finite number >= 0")
probability = _checked(float, lambda v: 0 < v < 1, "a number between 0 and 1 (exclusive)")
