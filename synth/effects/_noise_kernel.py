"""numba kernel of :func:`synth.effects.sensor.add_noise` for CPU float32 stacks (imported only when numba
is installed): the Poisson-Gaussian model in ONE parallel pass with its own random numbers.

Why not torch's draws: for the paper's 72-image stack (22 M pixels) the torch version spends
~110 ms in ``torch.randn`` and ~200 ms in ~8 further passes over the stack (clamp, scale,
comparisons, square root, masked writes, multiply-add, divide), each reading and writing ~90 MB
(measured, 1 thread, shared machine). Here every pixel is read once and written once, the normal
deviate made in the same loop.

Random numbers (the sampling method changed, not the model):
- Stream: splitmix64 (Steele, Lea & Flood 2014; passes BigCrush), one stream per block of
  ``BLOCK`` pixels started at ``mix(seed + mix(block))``, so the result depends on the seed and
  the pixel index only, never on the thread count. The 64-bit seed is drawn from the caller's
  torch generator, so a seeded scene renders the same noise every time.
- Normal deviates: the ziggurat method with 128 layers in Doornik's form ("An improved ziggurat
  method to generate normal random samples", 2005: layer index and uniform from separate bits,
  which removes the correlation of the original Marsaglia-Tsang 32-bit version), with the exact
  exponential-rejection tail beyond R = 3.4426. float64 deviates (53-bit uniforms), rounded to
  float32 like ``torch.randn``'s.
- Poisson (0 < e < 50 electrons): exact inversion by sequential search from k = 0 in float64.

Everything else is the torch version's float32 arithmetic in its order: ``e = max(v, 0) * fw``;
``std = sqrt(e + read^2)`` (``read`` at Poisson pixels, whose ``e`` becomes the Poisson count);
``v = (e + z std) / fw``. tests/test_synth_reference.py checks the normal deviates (moments,
tails beyond R, a Kolmogorov-Smirnov test, lag correlation) and the model's mean and variance.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

_JIT = dict(cache=True, error_model="numpy", nogil=True)
BLOCK = 1 << 14  # pixels per random stream and parallel task

# --- ziggurat tables (Doornik 2005, 128 layers) -------------------------------------------------
_ZIG_R = 3.442619855899
_ZIG_V = 9.91256303526217e-3  # area of every layer


def _tables():
    f = lambda x: math.exp(-0.5 * x * x)  # noqa: E731
    x = np.zeros(129)
    x[0] = _ZIG_V / f(_ZIG_R)
    x[1] = _ZIG_R
    for i in range(2, 128):
        x[i] = math.sqrt(-2.0 * math.log(_ZIG_V / x[i - 1] + f(x[i - 1])))
    x[128] = 0.0
    ratio = x[1:] / x[:-1]
    return x, ratio


ZIG_X, ZIG_RATIO = _tables()

_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_MASK7 = np.uint64(127)
_TWO_M53 = 1.0 / 9007199254740992.0  # 2^-53


@nb.njit(inline="always", **_JIT)
def _mix(z):
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@nb.njit(inline="always", **_JIT)
def _next(state):
    """splitmix64: (new state, 64 random bits)."""
    state = state + _GAMMA
    return state, _mix(state)


@nb.njit(inline="always", **_JIT)
def _uniform(bits):
    """(0, 1), 53 bits."""
    return (float(bits >> _S11) + 0.5) * _TWO_M53


@nb.njit(inline="always", **_JIT)
def _normal(state, zx, zr):
    """(new state, one standard normal deviate) by the ziggurat."""
    while True:
        state, bits = _next(state)
        i = int(bits & _MASK7)
        u = 2.0 * _uniform(bits) - 1.0  # the top 53 bits; the layer used the low 7
        if abs(u) < zr[i]:
            return state, u * zx[i]
        if i == 0:  # the tail beyond R (Marsaglia 1964)
            while True:
                state, b1 = _next(state)
                state, b2 = _next(state)
                x = math.log(_uniform(b1)) / zx[1]
                y = math.log(_uniform(b2))
                if -2.0 * y >= x * x:
                    break
            return state, (x - zx[1]) if u < 0 else (zx[1] - x)
        x = u * zx[i]
        f0 = math.exp(-0.5 * (zx[i] * zx[i] - x * x))
        f1 = math.exp(-0.5 * (zx[i + 1] * zx[i + 1] - x * x))
        state, b = _next(state)
        if f1 + _uniform(b) * (f0 - f1) < 1.0:
            return state, x


@nb.njit(inline="always", **_JIT)
def _poisson(state, lam):
    """(new state, Poisson(lam) count) by inversion (sequential search), lam < ~700."""
    state, b = _next(state)
    u = _uniform(b)
    k = 0
    p = math.exp(-lam)
    F = p
    while u > F:
        k += 1
        p *= lam / k
        F += p
        if k > lam and p < 1e-18 * F:  # F is 1 to rounding: u lies in the last ~1e-16
            break
    return state, k


@nb.njit(inline="always", **_JIT)
def _block_state(seed, block):
    return _mix(seed + _mix(np.uint64(block) * _GAMMA))


@nb.njit(parallel=True, **_JIT)
def add_noise_inplace(v, seed, full_well, read2, read, low_max, zx, zr):
    """The whole model in place on the 1-D float32 ``v`` (see the module docstring)."""
    n = v.shape[0]
    n_blocks = (n + BLOCK - 1) // BLOCK
    for b in nb.prange(n_blocks):
        state = _block_state(seed, b)
        for i in range(b * BLOCK, min(n, (b + 1) * BLOCK)):
            x = v[i]
            if x < 0:
                x = np.float32(0.0)
            e = x * full_well
            if e > 0 and e < low_max:
                state, k = _poisson(state, float(e))
                e = np.float32(k)
                std = read
            else:
                std = np.float32(math.sqrt(e + read2))
            state, z = _normal(state, zx, zr)
            v[i] = (e + np.float32(z) * std) / full_well


@nb.njit(parallel=True, **_JIT)
def normal_array(seed, out, zx, zr):
    """``out`` (1-D float64) filled with the kernel's standard normal deviates (tests)."""
    n = out.shape[0]
    for b in nb.prange((n + BLOCK - 1) // BLOCK):
        state = _block_state(seed, b)
        for i in range(b * BLOCK, min(n, (b + 1) * BLOCK)):
            state, out[i] = _normal(state, zx, zr)


@nb.njit(parallel=True, **_JIT)
def poisson_array(seed, lam, out):
    """``out`` (1-D int64) filled with Poisson(lam) counts of the kernel (tests)."""
    n = out.shape[0]
    for b in nb.prange((n + BLOCK - 1) // BLOCK):
        state = _block_state(seed, b)
        for i in range(b * BLOCK, min(n, (b + 1) * BLOCK)):
            state, out[i] = _poisson(state, lam)


def add_noise_numba(v: np.ndarray, seed: int, full_well: float, read: float, low_max: float) -> np.ndarray:
    """In place on the 1-D float32 ``v``; ``seed``: any integer (taken modulo 2^64)."""
    f32 = np.float32
    add_noise_inplace(v, np.uint64(seed % (1 << 64)), f32(full_well), f32(read * read), f32(read), f32(low_max),
                      ZIG_X, ZIG_RATIO)
    return v
