"""The network's input channel layout: one definition for the torch features (training,
:mod:`unwrap.learned.features`, whose docstring has the channel table) and the numpy ones
(inference, :mod:`unwrap.learned.fast_features`). No torch, no numpy.

A layout is a list of (group, number of channels), in channel order:

- ``physics``: ``prior`` (1), ``smoothed`` (one per smoothing window), ``disagreement`` (one per
  window), then the shared tail;
- ``prior_free``: ``phase_low`` (sin, cos, phase / pi: 3), the shared tail, ``method`` (one-hot: 3);
- shared tail: ``phase_high`` (sin, cos, phase / pi: 3), ``modulation`` (low, high: 2), ``valid`` (1).

    >>> channel_slices("physics")["phase_high"], input_channels("physics")
    (slice(5, 8, None), 11)
    >>> channel_slices("physics", windows=(9,))["modulation"], input_channels("physics", (5, 9, 21))
    (slice(6, 8, None), 13)
"""
from __future__ import annotations

from ..methods import PAIR_METHODS
from .errors import ModelError

KINDS = ("physics", "prior_free")
#: the network's method channel (prior-free one-hot)
METHOD_INDEX = {m: i for i, m in enumerate(PAIR_METHODS)}
MODULATION_GAIN = 4.0
#: Boxes (px) over which the smoothed priors filter the coarse phase.
SMOOTH_WINDOWS = (7, 15)
_TAIL = (("phase_high", 3), ("modulation", 2), ("valid", 1))


def channel_groups(kind: str, windows=SMOOTH_WINDOWS) -> list[tuple[str, int]]:
    """[(group, channels), ...] of a model kind, in channel order (module docstring)."""
    if kind == "physics":
        n = len(windows)
        return [("prior", 1), ("smoothed", n), ("disagreement", n), *_TAIL]
    if kind == "prior_free":
        return [("phase_low", 3), *_TAIL, ("method", len(METHOD_INDEX))]
    raise ModelError(f"model kind {kind!r}: expected one of {KINDS}")


def channel_slices(kind: str, windows=SMOOTH_WINDOWS) -> dict[str, slice]:
    """{group: slice of its channels} of a model kind."""
    out, start = {}, 0
    for name, count in channel_groups(kind, windows):
        out[name] = slice(start, start + count)
        start += count
    return out


def input_channels(kind: str, windows=SMOOTH_WINDOWS) -> int:
    """Number of input channels of a model kind."""
    return sum(count for _, count in channel_groups(kind, windows))
