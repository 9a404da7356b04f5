"""Exception and warning types of the unwrap package: ``UnwrapError``, its one error root (a
``ValueError``), and ``UnreliableFringesWarning``.

Every error names the input, the offending value and what was expected.
"""


class UnwrapError(ValueError):
    """Invalid input to phase shifting or phase unwrapping (shape, length, values, frequencies)."""


class UnreliableFringesWarning(UserWarning):
    """A frequency set / noise level whose predicted fringe-order error rate is above the limit."""
