"""Load the compiled kernels a decode will need on a background thread, while the frames are read.

A fresh process pays ~0.8-1 s before its first numba kernel runs (importing numba, which imports
``scipy.linalg``; numba's lowering registries; the kernel's cached machine code), all before any
pixel is touched, although it depends on nothing but the kernel's argument types. Reading the
frames (PNG decoding, in C without the GIL) and the phase fits (BLAS, numpy) leave the
interpreter free meanwhile, so :func:`start` runs that load on a daemon thread: the kernel is
called once on a tiny input with the argument types of the real call, which loads (or, the first
time on a machine, compiles) the same overload the decode then finds ready.

The decode waits for the thread (:meth:`Warmup.wait`) before it calls the kernel itself, so the
two never run at once. Whatever the warm-up raises is swallowed: the real call raises it again
where it belongs. Each kind of warm-up runs once per process (a batch of captures loads once).

SYNOPSIS

    w = warmup.fused_mf_for(first_frame, n_frequencies=3, max_steps=12)   # before reading
    stacks = read_frames(...)
    w.wait()
    mf_unwrap_stacks(stacks, ...)
"""
from __future__ import annotations

import threading

import numpy as np

_STARTED: dict = {}
_LOCK = threading.Lock()


class Warmup:
    """A warm-up running (or done) on a daemon thread; :meth:`wait` joins it (never raises)."""

    def __init__(self, fn, name: str):
        self.error = None
        self._thread = threading.Thread(target=self._run, args=(fn,), name=f"warmup-{name}", daemon=True)
        self._thread.start()

    def _run(self, fn):
        try:
            fn()
        except Exception as exc:     # the real call raises it again where it belongs
            self.error = exc

    def wait(self) -> None:
        self._thread.join()


def start(key, fn) -> Warmup:
    """Run ``fn()`` on a daemon thread, once per ``key`` per process; returns its :class:`Warmup`
    (the one started earlier for the same key, possibly done)."""
    with _LOCK:
        if key not in _STARTED:
            _STARTED[key] = Warmup(fn, str(key[0] if isinstance(key, tuple) else key))
        return _STARTED[key]


def started(key):
    """The :class:`Warmup` started for ``key`` in this process (running or done), else None."""
    with _LOCK:
        return _STARTED.get(key)


def fused_mf(dtype, n_frequencies: int, max_steps: int) -> Warmup:
    """Load the fused MF kernel (:mod:`unwrap.fused_mf`) for stacks of ``dtype`` (uint8 / uint16),
    ``n_frequencies`` stacks of at most ``max_steps`` frames: the kernel's types depend on the
    dtype, the number of stacks and whether the integer sums fit int16 (``max_steps`` x the
    dtype's maximum)."""
    dtype = np.dtype(dtype)
    top = int(np.iinfo(dtype).max) if dtype.kind in "ui" else 1
    F, N = max(2, int(n_frequencies)), max(3, int(max_steps))

    def run():
        from .fused_mf import mf_unwrap_stacks

        stacks = [np.full((3 if i < F - 1 else N, 2, 4), top // 2, dtype) for i in range(F)]
        mf_unwrap_stacks(stacks, [float(2 ** i) for i in range(F)], width=100.0, levels=True, fast=True)

    return start(("fused_mf", dtype.str, F, N * top < 2 ** 15), run)


def fused_mf_for(first_frame, n_frequencies: int, max_steps: int) -> Warmup:
    """:func:`fused_mf` for the dtype of the capture frame ``first_frame`` (a path), read on the
    warm-up thread itself."""
    def run():
        from .capture import read_image

        w = fused_mf(read_image(first_frame).dtype, n_frequencies, max_steps)
        w.wait()
        if w.error is not None:
            raise w.error

    return start(("fused_mf_for", str(first_frame), int(n_frequencies), int(max_steps)), run)


def plane_filter() -> Warmup:
    """Load the learned path's plane-fit kernel (:mod:`unwrap.learned._plane_kernel`, both boxes:
    one overload). Only a process that decodes several captures asks for it: from then on
    :func:`unwrap.learned.fast_features.plane_filter` waits for it and runs the compiled kernel
    instead of its C or numpy replica (the same bits)."""
    def run():
        from .learned._plane_kernel import plane_filter_kernel

        plane_filter_kernel(np.zeros((16, 16)), np.ones((16, 16), bool), 3)

    return start("plane_filter", run)
