"""Tiny array-namespace shim: the same formula runs on numpy arrays and torch tensors.

Only the handful of operations the unwrap formulas need; torch is imported lazily so numpy users
never pay for it.
"""
from __future__ import annotations

import math

import numpy as np

TWO_PI = 2.0 * math.pi

#: Half-width of the tie band of :func:`round_order`. A prior within this distance of a half
#: integer is a tie between two fringe orders that the data cannot decide; two computations of
#: the same prior (a BLAS kernel vs our fused sums, FMA or not, another thread count) differ by
#: ~1e-15, far inside the band, so every path and every machine resolves the tie the same way.
TIE_BAND = 1e-9


def is_torch(x) -> bool:
    return type(x).__module__.startswith("torch")


class _Numpy:
    name = "numpy"
    atan2 = staticmethod(np.arctan2)
    hypot = staticmethod(np.hypot)
    round = staticmethod(np.round)   # half to even; ties only at exact half integers
    ceil = staticmethod(np.ceil)
    floor = staticmethod(np.floor)
    where = staticmethod(np.where)
    isfinite = staticmethod(np.isfinite)
    abs = staticmethod(np.abs)
    float64 = np.float64

    @staticmethod
    def remainder(x, m):
        return np.mod(x, m)

    @staticmethod
    def asfloat64(x):
        return np.asarray(x, dtype=np.float64)

    @staticmethod
    def full_like(x, value, dtype=None):
        return np.full(np.shape(x), value, dtype=dtype or np.float64)

    @staticmethod
    def to_int32(x):
        return np.asarray(x).astype(np.int32)

    @staticmethod
    def nan():
        return np.nan


class _Torch:
    name = "torch"

    def __init__(self):
        import torch
        self.t = torch
        self.atan2 = torch.atan2
        self.hypot = torch.hypot
        self.round = torch.round
        self.floor = torch.floor
        self.ceil = torch.ceil
        self.where = torch.where
        self.isfinite = torch.isfinite
        self.abs = torch.abs
        self.float64 = torch.float64

    def remainder(self, x, m):
        return self.t.remainder(x, m)

    def asfloat64(self, x):
        return x.to(self.t.float64) if self.t.is_tensor(x) else self.t.as_tensor(x, dtype=self.t.float64)

    def full_like(self, x, value, dtype=None):
        return self.t.full_like(x, value, dtype=dtype or self.t.float64)

    def to_int32(self, x):
        return x.to(self.t.int32)

    @staticmethod
    def nan():
        return math.nan


_NUMPY = _Numpy()
_TORCH = None


def namespace(*arrays):
    """The numpy or torch shim for ``arrays`` (torch when any of them is a tensor)."""
    global _TORCH
    if any(is_torch(a) for a in arrays):
        if _TORCH is None:
            _TORCH = _Torch()
        return _TORCH
    return _NUMPY


def round_order(prior, xp=None):
    """Fringe order nearest to ``prior``, ties (within :data:`TIE_BAND` of a half integer) down.

    ``ceil(prior - 1/2 - TIE_BAND)``: 2.4 -> 2, 2.5 -> 2, 2.5 + 1e-15 -> 2, 2.5000001 -> 3.
    A prior halfway between two orders means the coarse and fine phases disagree by exactly pi:
    both orders explain the data equally, and plain rounding would let the last bit of the prior
    (which depends on the CPU's floating-point paths) choose. Float-valued result (numpy / torch).
    """
    xp = xp or namespace(prior)
    return xp.ceil(prior - (0.5 + TIE_BAND))


def wrap(x, xp=None):
    """Wrap phase (rad) into (-pi, pi], the range of atan2: ``x + 2*pi*floor((pi - x) / (2*pi))``."""
    xp = xp or namespace(x)
    return x + TWO_PI * xp.floor((math.pi - x) / TWO_PI)
