"""Exception and warning types of the unwrap package: ``UnwrapError``, its one error root (a
``ValueError``), ``DatasetSchemaError``, ``OutputError``, ``GlobalLightError``,
``FrameJitterError`` and ``UnreliableFringesWarning``.

Every error names the input, the offending value and what was expected.
"""


class UnwrapError(ValueError):
    """Invalid input to phase shifting or phase unwrapping (shape, length, values, frequencies)."""


class DatasetSchemaError(UnwrapError):
    """A file that is not a fringe-order dataset this code understands (or an incomplete one)."""


class OutputError(UnwrapError):
    """An output that cannot be written safely: locked by another process, or also an input
    (:mod:`unwrap.safe_output`)."""


class GlobalLightError(UnwrapError):
    """A capture on which the direct / global separation (:mod:`unwrap.global_light`) cannot be
    trusted (names the problem)."""


class FrameJitterError(UnwrapError):
    """A fringe set whose per-frame intensity fluctuation cannot be identified
    (:mod:`unwrap.frame_jitter`; names the reason: N = 3, too few pixels, uneven phases)."""


class UnreliableFringesWarning(UserWarning):
    """A frequency set / noise level whose predicted fringe-order error rate is above the limit."""
