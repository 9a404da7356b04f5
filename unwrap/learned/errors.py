"""Exception and warning types of the learned unwrapping (all ``ValueError`` subclasses via
:class:`unwrap.UnwrapError`, so callers that catch the package's errors catch these too)."""
from ..errors import UnwrapError


class ModelError(UnwrapError):
    """Invalid input to the learned unwrapping: data, model or frequencies it cannot handle."""


class ConfigError(ModelError):
    """A training / evaluation configuration with an unknown key or an out-of-range value."""


class CheckpointError(ModelError):
    """A checkpoint that is unreadable, corrupt, or made for another architecture."""


class DatasetTooSmallError(ModelError):
    """A training set with no (or too few) usable samples or valid pixels."""


class FrequencyRangeWarning(UserWarning):
    """The model is applied to a frequency ratio outside the range it was trained on."""
