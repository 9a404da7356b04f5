"""Exception type of the synth package: ``SynthError``, its one error root (a ``ValueError``, so
the command line reports it cleanly)."""


class SynthError(ValueError):
    """A scene, object, pattern or effect is invalid; the message names the key and the value."""
