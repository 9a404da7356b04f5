"""The render plan: every stage a render runs or skips, with the reason, kept as lines (``RenderResult.plan``)
and logged to the ``synth`` logger at DEBUG (``calib --debug`` shows them; ``calib render`` prints them)."""
from __future__ import annotations

import logging

LOG = logging.getLogger("synth")


class PlanLog:
    """Collects the plan lines and forwards them to ``log`` (a ``logging.Logger``) at ``level``."""

    def __init__(self, log: logging.Logger | None = None, level: int = logging.DEBUG):
        self.lines: list[str] = []
        self.log = log or LOG
        self.level = level

    def info(self, fmt, *args):
        """Record one plan line (``fmt % args``); the name keeps the ``Logger.info`` call shape."""
        line = fmt % args if args else fmt
        self.lines.append(line)
        self.log.log(self.level, line)

    @classmethod
    def of(cls, log) -> "PlanLog":
        """``log`` itself when it is a PlanLog, else a PlanLog forwarding to it."""
        return log if isinstance(log, cls) else cls(log)
