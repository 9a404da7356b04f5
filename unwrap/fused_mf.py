"""Fused N-step phase + multi-frequency unwrapping: integer frames in, absolute phase and k out, one pass.

``mf_unwrap_stacks`` gives the result of the readable reference
(:func:`unwrap.phase_shift.wrapped_phase` on each stack, then :func:`unwrap.temporal.mf_unwrap`
with the AND of the phase-shift masks), but, for 8/16-bit stacks, runs one compiled kernel
(:mod:`unwrap._fused_kernel` with numba; its C replica :mod:`unwrap._fused_c`, first choice where the
system has a C compiler: the same bits without numba's ~1 s start-up) that reads the frames of every
frequency once per pixel block, forms exact integer sums of the frames sharing a least-squares weight
(:func:`factor_weights`) and the float64 sums from them, and writes the absolute phase, fringe
order, validity, physics prior and the highest frequency's A and B, multithreaded over pixel
blocks. Otherwise (float input, torch, neither a C compiler nor numba) it runs the reference.

Agreement with the reference (tests/test_unwrap_fused.py: noisy 8/16-bit stacks with flat,
dark, saturated, low-modulation and clipped pixels, unequal shifts, a real capture): ``valid``
and ``B == 0`` identical; phase and prior within 1e-12 rad, A and B within 1e-12 relative.
``order`` is identical except at exact ties on the wrapped phase's +-pi cut (the sine sum
exactly 0, the cosine sum negative): the kernel's exact integer sums give phase pi, the
reference's BLAS rounding leaves +-4e-15 and gives pi or -pi; both then describe the same
absolute phase with k one apart (and the prior exactly one apart). Bit-identity would need the
BLAS library's summation order and fused multiply-adds, which numpy does not fix. After the
arctangent (own, at most 2 ulp from numpy's) the kernel repeats the reference's float64
operations (base phase, eq. 7 steps, rounding with ties down, masks) in the same order. A prior
that lands on a half integer (a tie between two orders: 2.4999999999999996 on one path,
2.5000000000000004 on the other) goes to the lower order on both paths (``TIE_BAND``), so the
kernel and the reference agree there on every machine.

SYNOPSIS

    >>> import numpy as np
    >>> from unwrap.patterns import absolute_phase, fringe_intensity
    >>> from unwrap.fused_mf import mf_unwrap_stacks
    >>> u = np.linspace(10, 900, 64)[None, :].repeat(4, 0)          # projector columns, (4, 64)
    >>> stacks = [np.stack([np.round(fringe_intensity(absolute_phase(u, f, 912), n, 12, 120, 90))
    ...                     for n in range(12)]).astype(np.uint8) for f in (1, 8, 48)]
    >>> r = mf_unwrap_stacks(stacks, (1, 8, 48), width=912)
    >>> bool(r.result.valid.all()), int(r.result.order.max()), r.result.phase.shape
    (True, 47, (4, 64))
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ._xp import TWO_PI
from .errors import UnwrapError
from .phase_shift import equal_shifts, least_squares_weights, wrapped_phase
from .temporal import Unwrapped, base_cut, ladder_wrap_orders, mf_unwrap, pattern_range

#: integer dtypes the kernel reads directly
FAST_DTYPES = (np.dtype(np.uint8), np.dtype(np.uint16))


@dataclass
class StackUnwrapped:
    """Result of :func:`mf_unwrap_stacks`.

    - ``result``: :class:`unwrap.temporal.Unwrapped` of the highest frequency (absolute phase in
      rad float64, NaN invalid; order int32, -1 invalid; valid; prior; levels when asked for).
    - ``modulation``, ``background``: B and A of the highest frequency's stack (input units,
      float64, pixel shape); B is 0 where the phase is undefined or the input out of range.
    - ``fast``: True when the compiled kernel ran, False for the reference path.
    """
    result: Unwrapped
    modulation: np.ndarray
    background: np.ndarray
    fast: bool


def native_kernel():
    """The C replica of the kernel (:mod:`unwrap._fused_c`, loaded and checked once per process), or
    None where it cannot be built (no C compiler, a cache that cannot be used)."""
    from ._fused_c import kernel
    return kernel(_kernel_weights)


def fast_available() -> bool:
    """True when a compiled kernel can run: the C replica (no numba imported), else numba's."""
    if native_kernel() is not None:
        return True
    try:
        from . import _fused_kernel  # noqa: F401
    except ImportError:
        return False
    return True


def _prepare(stacks, frequencies, shifts):
    if len(stacks) < 2:
        raise UnwrapError(f"MF needs at least two phase-shift stacks, got {len(stacks)}")
    f = np.asarray(frequencies, dtype=np.float64).reshape(-1)
    if f.size != len(stacks):
        raise UnwrapError(f"{len(stacks)} phase-shift stacks but {f.size} frequencies given: "
                          "they must match")
    if shifts is None:
        shifts = [None] * len(stacks)
    if len(shifts) != len(stacks):
        raise UnwrapError(f"{len(stacks)} phase-shift stacks but {len(shifts)} shift sets given")
    return f, list(shifts)


def mf_unwrap_stacks(stacks, frequencies, *, shifts=None, width=None, min_modulation: float = 0.0,
                     saturation="auto", valid_range=None, levels: bool = False,
                     fast="auto", out: StackUnwrapped | None = None) -> StackUnwrapped:
    """Wrapped phase of every stack + hierarchical MF unwrapping, fused when possible.

    ARGUMENTS
    - stacks: one (N_i, ...) phase-shift stack per frequency (step axis first; equal pixel
      shapes; N_i >= 3 may differ between frequencies).
    - frequencies: periods across the pattern, strictly increasing, the first <= 1.
    - shifts: optional list with one (N_i,) shift array (rad) or None (the paper's 2 pi n/N_i)
      per stack; unequal shifts are fine.
    - width, min_modulation, saturation, valid_range: as :func:`unwrap.temporal.mf_unwrap` and
      :func:`unwrap.phase_shift.wrapped_phase` (the same value for every stack).
    - levels: also return the intermediate (frequency, prior, k) of every step (costs writes).
    - fast: "auto" (kernel when it applies), True (kernel or UnwrapError saying why not), False
      (reference).
    - out: optional result of an earlier call on stacks of the same pixel count whose arrays
      the kernel overwrites (saves allocating and first-touching ~37 bytes per pixel when
      unwrapping a sequence); ignored by the reference path.
    RETURNED VALUE: :class:`StackUnwrapped`; equal to the reference within the tolerances in
    the module docstring.
    """
    f, shift_list = _prepare(stacks, frequencies, shifts)
    if fast not in ("auto", True, False):
        raise UnwrapError(f"fast must be 'auto', True or False, got {fast!r}")
    reason = None if fast is False else _why_not_fast(stacks, f, width, saturation, valid_range)
    if fast is True and reason is not None:
        raise UnwrapError(f"the fused MF kernel does not apply: {reason}")
    if fast is False or reason is not None:
        return _reference(stacks, f, shift_list, width, min_modulation, saturation, valid_range,
                          levels)
    return _fused(stacks, f, shift_list, width, min_modulation, saturation, valid_range, levels,
                  out)


def _why_not_fast(stacks, f, width, saturation, valid_range):
    """None when the kernel applies, else the reason (a phrase)."""
    if not fast_available():
        return "neither a C compiler nor numba is available"
    if any(type(s).__module__.startswith("torch") for s in stacks):
        return "torch tensors (the kernel reads numpy arrays)"
    arrays = [s for s in stacks if isinstance(s, np.ndarray)]
    if len(arrays) != len(stacks):
        return "stacks are not numpy arrays"
    dtypes = {a.dtype for a in arrays}
    if len(dtypes) != 1 or arrays[0].dtype not in FAST_DTYPES:
        return f"stack dtypes {sorted(str(d) for d in dtypes)} (the kernel reads uint8 or uint16)"
    if any(a.ndim < 2 for a in arrays):
        return "a stack without pixel axes"
    if len({a.shape[1:] for a in arrays}) != 1:
        return "stacks differ in pixel shape"
    if not (np.all(np.isfinite(f)) and np.all(f > 0) and np.all(np.diff(f) > 0)
            and f[0] <= 1.0 + 1e-12):
        return f"frequencies {f.tolist()} are not an MF ladder"
    c = base_cut(f[0], width)
    if not math.pi - c < TWO_PI:
        return "the base-phase cut needs the general remainder"
    if saturation is not None and saturation != "auto" and not np.isfinite(float(saturation)):
        return "a non-finite saturation level"
    if valid_range is not None and not np.all(np.isfinite(np.asarray(valid_range, np.float64))):
        return "a non-finite valid_range"
    return None


def _reference(stacks, f, shift_list, width, min_modulation, saturation, valid_range, levels):
    phases, valid, last = [], None, None
    for st, sh in zip(stacks, shift_list):
        w = wrapped_phase(st, sh, min_modulation=min_modulation, saturation=saturation,
                          valid_range=valid_range)
        phases.append(w.phase)
        valid = w.valid if valid is None else valid & w.valid
        last = w
    res = mf_unwrap(phases, f, width=width, valid=valid)
    if not levels:
        res.levels = []
    return StackUnwrapped(res, np.asarray(last.B), np.asarray(last.A), False)


#: weights whose magnitudes agree within this many float64 epsilons of the row's largest weight
#: share one integer group; smaller weights count as zero (see factor_weights)
MERGE_EPS = 16


def factor_weights(P, merge_eps: float = MERGE_EPS):
    """Factor least-squares weights ``P`` (3, N) as ``W @ Q``: W (3, G) float64, Q (G, N) in {-1, 0, 1}.

    Frames whose weight in a row of P has (nearly) the same magnitude form a group whose signed
    sum ``Q[g] @ I`` is exact in integer arithmetic; the float64 work is then G multiply-adds
    per output instead of N. For the paper's equal shifts the rows of P hold a few values
    (``2/N cos(2 pi n/N)`` repeats) up to pinv's rounding: N = 12 gives G = 7 groups. Merging
    changes each weight by at most ``max|P - W @ Q|`` (9.7e-17 for N = 12, 2.3e-16 for N = 3,
    0 when nothing merges, e.g. unequal shifts), the size of pinv's own rounding; the sums
    differ from ``P @ I`` by at most that times ``sum_n I_n``.
    """
    P = np.asarray(P, np.float64)
    N = P.shape[1]
    columns, q_rows, w_cols = {}, [], []
    for r in range(3):
        row = P[r]
        tol = merge_eps * np.finfo(np.float64).eps * float(np.abs(row).max())
        order = np.argsort(np.abs(row), kind="stable")
        clusters, current = [], [int(order[0])]
        for n in order[1:]:
            if abs(row[n]) - abs(row[current[0]]) <= tol:
                current.append(int(n))
            else:
                clusters.append(current)
                current = [int(n)]
        clusters.append(current)
        for members in clusters:
            magnitude = np.abs(row[members])
            if magnitude.max() <= tol:
                continue  # pinv's rounding of a zero weight
            q = np.zeros(N, np.int8)
            q[members] = np.sign(row[members]).astype(np.int8)
            key = q.tobytes()
            if key not in columns:
                columns[key] = len(q_rows)
                q_rows.append(q)
                w_cols.append(np.zeros(3))
            w_cols[columns[key]][r] = float(np.mean(magnitude))
    return np.array(w_cols, np.float64).T.copy(), np.array(q_rows, np.int8)


@lru_cache(maxsize=32)
def _kernel_weights(shift_sets: tuple):
    """Factored weights of every stack in the kernel's flat layout, built once per shift sets.

    shift_sets: one tuple of shifts (rad) per stack. Returns (W (3, sum G) float64,
    goff (F+1,), grp_start (sum G + 1,), ent_n (E,) int64, ent_s (E,) int32, sum_all (F,): the
    group of each stack that sums every frame with sign +1, or -1), read-only.
    """
    W_cols, goff, grp_start, ent_n, ent_s, sum_all = [], [0], [0], [], [], []
    for sh in shift_sets:
        W, Q = factor_weights(least_squares_weights(sh))  # raises for degenerate shifts
        W_cols.append(W)
        everything = np.flatnonzero(np.all(Q == 1, axis=1))
        sum_all.append(int(everything[0]) if everything.size else -1)
        for q in Q:
            nz = np.flatnonzero(q)
            ent_n.extend(nz.tolist())
            ent_s.extend(q[nz].tolist())
            grp_start.append(len(ent_n))
        goff.append(goff[-1] + Q.shape[0])
    out = (np.ascontiguousarray(np.concatenate(W_cols, axis=1)), np.asarray(goff, np.int64),
           np.asarray(grp_start, np.int64), np.asarray(ent_n, np.int64),
           np.asarray(ent_s, np.int32), np.asarray(sum_all, np.int64))
    for a in out:
        a.setflags(write=False)
    return out


def _outputs(out, n_pix, n_lev):
    """Output arrays: fresh, or those of ``out`` (a StackUnwrapped of the same size) reused."""
    if out is None:
        return (np.empty(n_pix, np.float64), np.empty(n_pix, np.int32), np.empty(n_pix, np.bool_),
                np.empty(n_pix, np.float64), np.empty(n_pix, np.float64),
                np.empty(n_pix, np.float64))
    arrays = (out.result.phase, out.result.order, out.result.valid, out.result.prior,
              out.background, out.modulation)
    dtypes = (np.float64, np.int32, np.bool_, np.float64, np.float64, np.float64)
    flat = []
    for a, dt in zip(arrays, dtypes):
        if not (isinstance(a, np.ndarray) and a.dtype == dt and a.size == n_pix
                and a.flags.c_contiguous and a.flags.writeable):
            raise UnwrapError("out: expected the StackUnwrapped of an earlier fast call on stacks of "
                              "the same pixel count")
        flat.append(a.reshape(n_pix))
    return tuple(flat)


def _fused(stacks, f, shift_list, width, min_modulation, saturation, valid_range, levels,
           out=None):
    native = native_kernel()
    pix_shape = stacks[0].shape[1:]
    n_pix = int(np.prod(pix_shape))
    flat = tuple(np.ascontiguousarray(s).reshape(s.shape[0], n_pix) for s in stacks)
    max_value = int(np.iinfo(flat[0].dtype).max)
    shift_sets, n_max = [], 0
    for st, sh in zip(flat, shift_list):
        N = st.shape[0]
        sh = equal_shifts(N) if sh is None else np.asarray(sh, dtype=np.float64).reshape(-1)
        if sh.size != N:
            raise UnwrapError(f"stack has {N} frames but {sh.size} phase shifts were given: "
                              "they must match")
        if N * max_value >= 2 ** 31:
            raise UnwrapError(f"{N} frames of {st.dtype}: integer sums could overflow int32")
        n_max = max(n_max, N)
        shift_sets.append(tuple(sh.tolist()))
    W, goff, grp_start, ent_n, ent_s, sum_all = _kernel_weights(tuple(shift_sets))
    if saturation == "auto":
        saturation = float(max_value)
    sat = math.inf if saturation is None else float(saturation)
    lo, hi = (-math.inf, math.inf) if valid_range is None else (float(valid_range[0]),
                                                              float(valid_range[1]))
    ratios = np.array([0.0] + [f[i] / f[i - 1] for i in range(1, len(f))], dtype=np.float64)
    kmax = float(math.floor(f[-1] + 0.5))
    n_lev = len(f) - 1 if levels else 0
    phase, order, valid, prior, A, B = _outputs(out, n_pix, n_lev)
    lev_prior = np.empty((n_lev, n_pix if levels else 0), np.float64)
    lev_k = np.empty_like(lev_prior)
    sum_type = np.empty(0, np.int16 if n_max * max_value < 2 ** 15 else np.int32)
    p_lo, p_hi = pattern_range(float(f[-1]), width)
    wrap = float(ladder_wrap_orders(f, f[0]) or 0)
    args = (W, goff, grp_start, ent_n, ent_s, sum_all, ratios, base_cut(f[0], width), sat, lo, hi,
            float(min_modulation or 0.0), kmax, p_lo, p_hi, wrap, phase, order, valid, prior, A, B, lev_prior, lev_k)
    if native is not None:     # the same bits as numba's kernel, without importing numba (module docstring)
        from ._fused_c import run
        run(native, flat, *args)
    else:
        from . import _fused_kernel as K
        K.mf_kernel(flat, sum_type, *args)
    r = lambda x: x.reshape(pix_shape)  # noqa: E731
    lev = [(float(f[i + 1]), r(lev_prior[i]), r(lev_k[i])) for i in range(n_lev)]
    res = Unwrapped(r(phase), r(order), r(valid), r(prior), float(f[-1]), "mf", lev)
    return StackUnwrapped(res, r(B), r(A), True)


__all__ = ["StackUnwrapped", "mf_unwrap_stacks", "fast_available", "factor_weights"]
