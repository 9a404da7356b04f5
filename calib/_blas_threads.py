"""One BLAS thread while the bundle adjustment runs (a private helper of ``calib.ba_solver``).

The adjustment's linear algebra is many small matrices (6 x 6 pose blocks, the G x G reduced
matrix with G <= 42). numpy's bundled OpenBLAS runs its LAPACK routines on every core even for
those, and waking and synchronising the threads costs far more than the arithmetic: inverting
nine 6 x 6 blocks took 95 us of CPU with the default threads and 8 us with one, the 22 x 22 reduced
matrix 99 us and 11 us (measured on the 2-core development machine). ``single_threaded_blas()``
sets OpenBLAS to one thread for the duration of a ``with`` block and restores the previous count;
where no OpenBLAS with that control is loaded it does nothing. The setting is process-wide: other
threads using BLAS meanwhile run single-threaded too.

SYNOPSIS

    >>> import numpy as np
    >>> from calib._blas_threads import single_threaded_blas
    >>> with single_threaded_blas():
    ...     x = np.linalg.inv(np.eye(3))
    >>> float(x[0, 0])
    1.0
"""
from __future__ import annotations

import ctypes
import glob
import os
from contextlib import contextmanager

_CONTROL = None          # (get, set) of the loaded OpenBLAS, () where there is none


def _openblas_control():
    global _CONTROL
    if _CONTROL is None:
        _CONTROL = ()
        import numpy

        libs = glob.glob(os.path.join(os.path.dirname(numpy.__file__), os.pardir, "numpy.libs", "*openblas*"))
        try:                                  # a system numpy: the OpenBLAS this process mapped
            with open("/proc/self/maps") as maps:
                libs += sorted({line.split()[-1] for line in maps if "openblas" in line and ".so" in line})
        except OSError:
            pass
        for path in libs:
            try:
                lib = ctypes.CDLL(path)
            except OSError:
                continue
            for suffix in ("64_", ""):
                get = getattr(lib, f"openblas_get_num_threads{suffix}", None)
                put = getattr(lib, f"openblas_set_num_threads{suffix}", None)
                if get is not None and put is not None:
                    get.restype, put.argtypes = ctypes.c_int, [ctypes.c_int]
                    _CONTROL = (get, put)
                    return _CONTROL
    return _CONTROL


@contextmanager
def single_threaded_blas():
    """Run the block with one OpenBLAS thread (see the module docstring)."""
    control = _openblas_control()
    if not control:
        yield
        return
    get, put = control
    before = get()
    put(1)
    try:
        yield
    finally:
        put(before)
