"""A one-line training progress bar (steps, loss, samples/s, ETA) on stderr, or a log line every
``every_s`` seconds when stderr is not a terminal (a batch job's log file)."""
from __future__ import annotations

import sys
import time


def _hms(s: float) -> str:
    if s != s or s < 0:
        return "?"
    s = int(s)
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


class StepBar:
    """``bar = StepBar(total, start=done); bar.update(step, loss=..., samples_per_s=...)``."""

    def __init__(self, total: int, *, start: int = 0, label: str = "train", stream=None,
                 every_s: float = 15.0, enabled: bool = True):
        self.total, self.start, self.label, self.enabled = int(total), int(start), label, enabled
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.every_s, self.t0, self.last = every_s, time.perf_counter(), -1e9

    def update(self, step: int, force: bool = False, **values):
        if not self.enabled:
            return
        now = time.perf_counter()
        if not force and now - self.last < (0.25 if self.tty else self.every_s):
            return
        self.last = now
        done = step - self.start
        rate = done / (now - self.t0) if now > self.t0 else 0.0
        eta = (self.total - step) / rate if rate > 0 else float("nan")
        fill = int(24 * step / max(self.total, 1))
        vals = "  ".join(f"{k} {v:.4g}" for k, v in values.items())
        line = (f"{self.label} [{'#' * fill}{'.' * (24 - fill)}] {step}/{self.total} "
                f"{_hms(now - self.t0)}<{_hms(eta)}  {vals}")
        self.stream.write(("\r" + line[:160]) if self.tty else line + "\n")
        self.stream.flush()

    def close(self):
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()
