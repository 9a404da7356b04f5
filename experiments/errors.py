"""Exception type of experiments: ``ExperimentError``, its one error root (a ``ValueError``)."""


class ExperimentError(ValueError):
    """An experiment's inputs are missing or do not allow the comparison it makes."""
