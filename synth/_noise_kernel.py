"""numba passes of :func:`synth.sensor.add_noise` for CPU float32 stacks (imported only when numba
is installed).

The torch version makes ~8 full passes over the stack (clamp, scale, two comparisons, square root,
masked writes, multiply-add, divide), each reading and writing ~90 MB for the paper's 72-image
stack. Here the same float32 operations, in the same order, run in three fused passes: (A)
electrons in place and per-block counts of the Poisson pixels, (B) their electron counts gathered
in float64 for ``torch.poisson``, (C) ``(e + z std) / full_well``. The random numbers are the
torch version's (``z`` from ``torch.randn``, then ``torch.poisson`` on the same values in the same
order, from the caller's generator), so the noise is the same draw as the torch version's and its
statistics are the model's by construction (tests/test_synth_reference.py). The one difference:
the square root here is correctly rounded, torch's vectorised float32 one is not (one ulp off
in ~15 % of pixels, measured), so outputs differ by at most a few 1e-8 (one ulp of the noise
standard deviation times |z|, then one rounding of the value).
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

_JIT = dict(cache=True, error_model="numpy", nogil=True)
BLOCK = 1 << 16  # elements per parallel block


@nb.njit(parallel=True, **_JIT)
def electrons_and_counts(v, full_well, low_max, counts):
    """In place ``v = max(v, 0) * full_well``; ``counts[b]`` = pixels of block b with 0 < e < low_max."""
    n = v.shape[0]
    for b in nb.prange(counts.shape[0]):
        c = 0
        for i in range(b * BLOCK, min(n, (b + 1) * BLOCK)):
            x = v[i]
            if x < 0:
                x = np.float32(0.0)
            e = x * full_well
            v[i] = e
            if e > 0 and e < low_max:
                c += 1
        counts[b] = c


@nb.njit(parallel=True, **_JIT)
def gather_low(v, low_max, offsets, low_e):
    """The electron counts (float64) of the Poisson pixels, block by block in index order."""
    n = v.shape[0]
    for b in nb.prange(offsets.shape[0] - 1):
        k = offsets[b]
        for i in range(b * BLOCK, min(n, (b + 1) * BLOCK)):
            e = v[i]
            if e > 0 and e < low_max:
                low_e[k] = e
                k += 1


@nb.njit(parallel=True, **_JIT)
def add_and_scale(v, z, read2, read, full_well, low_max, offsets, shot):
    """``v = (e + z sqrt(e + read^2)) / full_well``, with ``e -> shot`` and ``sqrt -> read`` at the
    Poisson pixels (all float32, the torch version's operations)."""
    n = v.shape[0]
    for b in nb.prange(offsets.shape[0] - 1):
        k = offsets[b]
        for i in range(b * BLOCK, min(n, (b + 1) * BLOCK)):
            e = v[i]
            if e > 0 and e < low_max:
                std = read
                e = shot[k]
                k += 1
            else:
                std = math.sqrt(e + read2)
            v[i] = (e + z[i] * std) / full_well


def add_noise_numba(v: np.ndarray, z: np.ndarray, full_well: float, read: float, low_max: float, poisson):
    """In place on the 1-D float32 ``v`` with normals ``z`` (float32, same size); ``poisson`` maps
    a float64 array of rates to float32 draws."""
    f32 = np.float32
    counts = np.empty((v.size + BLOCK - 1) // BLOCK, dtype=np.int64)
    electrons_and_counts(v, f32(full_well), f32(low_max), counts)
    offsets = np.zeros(counts.size + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    shot = np.zeros(0, dtype=np.float32)
    if offsets[-1] > 0:
        low_e = np.empty(offsets[-1], dtype=np.float64)
        gather_low(v, f32(low_max), offsets, low_e)
        shot = np.ascontiguousarray(poisson(low_e), dtype=np.float32)
    add_and_scale(v, z, f32(read * read), f32(read), f32(full_well), f32(low_max), offsets, shot)
    return v
