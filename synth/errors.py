"""Exception types of the synth package: ``SynthError``, its one error root (a ``ValueError``, so
the command line reports it cleanly), ``ExportConfigError`` and ``ExportError``."""


class SynthError(ValueError):
    """A scene, object, pattern or effect is invalid; the message names the key and the value."""


class ExportConfigError(SynthError):
    """An invalid dataset-export config (the message names the key)."""


class ExportError(SynthError):
    """The export cannot go on (output not writable, disk full, foreign or missing shards)."""
