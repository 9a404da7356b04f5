"""The package's small thread pools (frame decoding in :mod:`unwrap.capture`, chunk deflating in
:mod:`unwrap.phase_io`): one per name, made on first use, at most 4 threads (the work they take,
OpenCV's decoders and zlib, runs without the GIL).

A forked child inherits a pool object whose threads do not exist in it: work submitted there would
wait forever (a ``multiprocessing`` or DataLoader worker forked after the parent read a capture).
So the pools are forgotten in the child after a fork, and it makes its own on first use.
"""
from __future__ import annotations

import os
import threading

_POOLS: dict = {}
_LOCK = threading.Lock()


def pool(name: str):
    """The process's :class:`concurrent.futures.ThreadPoolExecutor` named ``name`` (made once)."""
    with _LOCK:
        if name not in _POOLS:
            from concurrent.futures import ThreadPoolExecutor

            _POOLS[name] = ThreadPoolExecutor(max_workers=min(4, os.cpu_count() or 1), thread_name_prefix=name)
        return _POOLS[name]


def _forget_in_child() -> None:
    global _LOCK
    _LOCK = threading.Lock()     # the parent may have held it while forking
    _POOLS.clear()


if hasattr(os, "register_at_fork"):     # POSIX; elsewhere there is no fork
    os.register_at_fork(after_in_child=_forget_in_child)
