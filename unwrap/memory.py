"""Keep a process's resident memory near what it uses: a fixed glibc mmap threshold.

glibc's malloc serves a request above the *mmap threshold* (128 KiB at start) with its own mapping,
returned to the system when freed; smaller ones come from the heap, whose free parts mostly stay
resident. The threshold is dynamic: freeing a mapped block raises it to that block's size (up to
32 MiB), so after the first few image-sized arrays are freed every later map-sized temporary
(5 MB for a 900 x 700 float64 map) comes from the heap, and the peak resident memory becomes what
the heap has ever held, not what is alive. Fixing the threshold (``mallopt(M_MMAP_THRESHOLD)``, which
also turns the dynamic rule off) keeps large blocks mapped. Measured on ``calib unwrap --model
model.onnx`` at 900 x 700 (docs/speed.md): peak 510 -> 420 MB with every map bitwise the same, for
+0.75 s of system time (a fresh mapping, page faults included, for every large temporary and
every buffer of the network's forward: ~15 % of the command's CPU time); at 4 MiB 430 MB for
+0.45 s, at 16 MiB 487 MB for +0.07 s.

It is a setting of the whole process: ``calib unwrap --low-memory`` asks for it; library code does
not set it. It outlasts the command in a Python process that runs it in-process
(``sltwin.cli.main([... "--low-memory"])``): glibc has no call that restores the dynamic threshold.

:func:`trim_heap` is the one-off, setting-free counterpart (``malloc_trim(0)``: the heap's free
pages go back to the system now, the threshold stays dynamic). The learned path calls it before
the network's forward, the peak of ``calib unwrap --model``: there the heap held ~50-130 MB of
freed maps on ~160-190 MB live (900 x 700, docs/speed.md, session 9).
"""
from __future__ import annotations

import sys

#: glibc's ``M_MMAP_THRESHOLD`` parameter number (malloc.h)
_M_MMAP_THRESHOLD = -3
#: glibc's initial threshold, kept fixed
DEFAULT_THRESHOLD = 128 * 1024


def fix_mmap_threshold(nbytes: int = DEFAULT_THRESHOLD) -> bool:
    """Fix glibc's mmap threshold at ``nbytes`` for the rest of the process (module docstring).
    True when set; False where the C library is not glibc (nothing changes)."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        libc = ctypes.CDLL("libc.so.6")
        return bool(libc.mallopt(_M_MMAP_THRESHOLD, int(nbytes)))
    except (OSError, AttributeError):       # musl or another libc without mallopt
        return False


def trim_heap() -> bool:
    """Give the free pages of glibc's heaps back to the system now (``malloc_trim(0)``; module
    docstring). True when glibc released memory; False when there was none to release or the C
    library is not glibc (nothing changes)."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        return bool(ctypes.CDLL("libc.so.6").malloc_trim(0))
    except (OSError, AttributeError):       # musl or another libc without malloc_trim
        return False
