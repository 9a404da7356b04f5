"""Exception type of the synth package (a ValueError, so the CLI reports it cleanly)."""


class SynthError(ValueError):
    """A scene, object, pattern or effect is invalid; the message names the key and the value."""
