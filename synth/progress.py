"""A small progress bar for long loops: count, rate, ETA on one stderr line (a terminal), or a
log line every ``every_s`` seconds (a file or a batch job's log)."""
from __future__ import annotations

import sys
import time


def _hms(s: float) -> str:
    s = int(max(s, 0))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


class Progress:
    """``with Progress(total, "export") as bar: ... bar.update()``; ``done`` counts what was already
    finished before (a resumed run), so rate and ETA count only this run's work."""

    def __init__(self, total: int, label: str = "", *, done: int = 0, stream=None, every_s: float = 10.0,
                 enabled: bool = True, unit: str = "samples"):
        self.total, self.label, self.n, self.start_n = total, label, done, done
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.every_s, self.enabled, self.unit = every_s, enabled, unit
        self.t0 = time.perf_counter()
        self.last = 0.0

    def __enter__(self):
        self._show(force=True)
        return self

    def __exit__(self, *exc):
        self._show(force=True)
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()

    def update(self, k: int = 1, note: str = ""):
        self.n += k
        self._show(note=note)

    def line(self, note: str = "") -> str:
        el = time.perf_counter() - self.t0
        done = self.n - self.start_n
        rate = done / el if el > 0 else 0.0
        eta = (self.total - self.n) / rate if rate > 0 else float("nan")
        width = 24
        fill = int(width * self.n / max(self.total, 1))
        bar = "#" * fill + "." * (width - fill)
        eta_s = _hms(eta) if eta == eta else "?"
        return (f"{self.label} [{bar}] {self.n}/{self.total} {self.unit}, {rate:.2f}/s, elapsed {_hms(el)}, "
                f"ETA {eta_s}" + (f"  {note}" if note else ""))

    def _show(self, force: bool = False, note: str = ""):
        if not self.enabled:
            return
        now = time.perf_counter()
        if self.tty:
            if force or now - self.last > 0.2:
                self.stream.write("\r" + self.line(note)[:150])
                self.stream.flush()
                self.last = now
        elif force or now - self.last >= self.every_s:
            self.stream.write(self.line(note) + "\n")
            self.stream.flush()
            self.last = now
