"""Exception type of the application layer: ``CommandError`` (a ``ValueError``), for an option
or an input of a command that cannot be used. The command line ends such a command, as every
toolkit error, with exit code 2 and the message, never a traceback."""


class CommandError(ValueError):
    """An option or input of a command is invalid (the message names it and what was expected)."""
