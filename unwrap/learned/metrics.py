"""Fringe-order error rates and the confidence curve.

Error rate = wrong fringe orders / counted pixels. A pixel is counted when the inputs are valid
(lit, not shadowed, modulation above the export's threshold in both patterns, not saturated,
finite: the dataset's ``valid``) and a true / reference order exists (``order_true >= 0``).
Every method is scored on the same pixels; a method that gives no order there (e.g. -1) counts
as wrong.

SYNOPSIS

    >>> import numpy as np
    >>> from unwrap.learned.metrics import ErrorCount, keep_drop_curve
    >>> c = ErrorCount.of(np.array([3, 4, 5]), np.array([3, 4, 6]), np.array([True, True, True]))
    >>> c.wrong, c.counted, round(c.rate, 4)
    (1, 3, 0.3333)
    >>> keep_drop_curve(np.array([0.9, 0.8, 0.3]), np.array([False, False, True]), drops=(0.0, 1/3))
    [(0.0, 0.3333333333333333), (0.3333333333333333, 0.0)]
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class ErrorCount:
    """Wrong / counted pixels, additive over frames (``a + b``)."""
    wrong: int = 0
    counted: int = 0

    @property
    def rate(self) -> float:
        return self.wrong / self.counted if self.counted else float("nan")

    def __add__(self, other: "ErrorCount") -> "ErrorCount":
        return ErrorCount(self.wrong + other.wrong, self.counted + other.counted)

    @classmethod
    def of(cls, order, order_true, mask) -> "ErrorCount":
        """Count ``order != order_true`` over ``mask & (order_true >= 0)`` (arrays or tensors)."""
        order, order_true, mask = (np.asarray(a) for a in (order, order_true, mask))
        m = mask.astype(bool) & (order_true >= 0)
        return cls(int(((order != order_true) & m).sum()), int(m.sum()))


def keep_drop_curve(confidence, wrong, drops=(0.0, 0.01, 0.02, 0.05, 0.1, 0.2)):
    """[(fraction dropped, error rate of the kept pixels)]: drop the least confident pixels first.

    ``confidence`` and ``wrong`` (bool) over the counted pixels (1-D). A confidence that finds the
    wrong orders makes the kept error rate fall fast as the dropped fraction grows; a random one
    leaves it flat. Ties in confidence are broken by position (stable sort)."""
    conf = np.asarray(confidence, dtype=np.float64).ravel()
    bad = np.asarray(wrong, dtype=bool).ravel()
    n = conf.size
    if n == 0:
        return [(float(d), float("nan")) for d in drops]
    order = np.argsort(conf, kind="stable")
    bad_sorted = bad[order]
    tail = np.concatenate([np.cumsum(bad_sorted[::-1])[::-1], [0]])   # wrong among positions >= i
    out = []
    for d in drops:
        k = int(round(float(d) * n))
        kept = n - k
        out.append((float(d), float(tail[k] / kept) if kept else float("nan")))
    return out
