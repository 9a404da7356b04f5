"""N-step least-squares phase shifting: wrapped phase, background A, modulation B and masks.

Model of frame n (DESIGN.md, eq. 5 of the paper's supplementary):
``I_n = A + B*cos(phi - delta_n)`` with known shifts ``delta_n`` (radians; the paper's
``2*pi*n/N`` by default, any N >= 3 and any set of at least three distinct shifts allowed).
Writing ``I_n = A + C*cos(delta_n) + S*sin(delta_n)`` with ``C = B cos(phi)``, ``S = B sin(phi)``
makes the fit linear: ``[A, C, S] = P @ I`` with ``P = pinv(M)``, ``M = [1, cos delta, sin delta]``
(N, 3). For equal shifts ``P`` reduces to the mean and ``2/N * sum I_n cos/sin(delta_n)``, so
``phi = atan2(sum I_n sin(2 pi n/N), sum I_n cos(2 pi n/N))`` exactly as in DESIGN.md (eq. 6).

One implementation serves numpy arrays and torch tensors (differentiable; the learned model in a
later stage uses it). Results are float64.

SYNOPSIS

    >>> import numpy as np
    >>> from unwrap.patterns import fringe_intensity
    >>> from unwrap.phase_shift import wrapped_phase
    >>> phi_true = np.linspace(-3, 3, 7)
    >>> stack = np.stack([fringe_intensity(phi_true, n, 4, A=100, B=50) for n in range(4)])
    >>> w = wrapped_phase(stack)
    >>> bool(np.allclose(w.phase, phi_true)), bool(np.allclose(w.B, 50)), bool(w.valid.all())
    (True, True, True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ._xp import is_torch, namespace
from .errors import UnwrapError


@dataclass
class WrappedPhase:
    """Result of :func:`wrapped_phase`; every array has the pixel shape of the stack.

    - ``phase``: wrapped phase in (-pi, pi] (rad, float64), NaN where not ``valid`` when the call
      asked for ``fill_invalid`` (default).
    - ``A``: background, ``B``: modulation (>= 0), in the units of the input (float64).
    - ``low_modulation``: ``B < min_modulation`` (or B == 0: phase undefined).
    - ``saturated``: some frame reached the saturation level.
    - ``out_of_range``: some frame is NaN/inf or outside ``valid_range``.
    - ``valid``: none of the above.
    """
    phase: object
    A: object
    B: object
    low_modulation: object
    saturated: object
    out_of_range: object
    valid: object


def equal_shifts(steps: int) -> np.ndarray:
    """The paper's shifts ``2*pi*n/N`` for n = 0..N-1 (rad), float64 (N,)."""
    if int(steps) != steps or steps < 3:
        raise UnwrapError(f"steps = {steps!r}: N-step phase shifting needs an integer N >= 3")
    return 2.0 * math.pi * np.arange(int(steps), dtype=np.float64) / int(steps)


@lru_cache(maxsize=64)
def _weights_cached(shifts: tuple) -> np.ndarray:
    delta = np.asarray(shifts, dtype=np.float64)
    M = np.stack([np.ones_like(delta), np.cos(delta), np.sin(delta)], axis=1)  # (N, 3)
    sv = np.linalg.svd(M, compute_uv=False)
    if sv[-1] <= 1e-9 * sv[0]:
        raise UnwrapError(
            f"phase shifts {np.round(delta, 6).tolist()} rad do not determine A, B and phi: at least "
            "three shifts distinct modulo 2*pi are needed")
    P = np.linalg.pinv(M)  # (3, N): rows give A, B cos(phi), B sin(phi)
    P.setflags(write=False)
    return P


def least_squares_weights(shifts) -> np.ndarray:
    """The (3, N) float64 matrix mapping a pixel's N intensities to ``[A, B cos phi, B sin phi]``.

    ARGUMENTS: shifts = (N,) known phase shifts delta_n (rad), N >= 3, at least three distinct
    modulo 2*pi. Built once per shift set (cached).
    """
    delta = np.asarray(shifts, dtype=np.float64).reshape(-1)
    if delta.size < 3:
        raise UnwrapError(f"{delta.size} phase shifts given: N-step phase shifting needs N >= 3")
    if not np.all(np.isfinite(delta)):
        raise UnwrapError(f"phase shifts must be finite, got {delta.tolist()}")
    return _weights_cached(tuple(np.mod(delta, 2 * math.pi).tolist()))


def phase_noise_gain(shifts) -> float:
    """Factor g with ``var(phi) = g * sigma^2 / B^2`` for the least-squares fit (high SNR).

    For equal shifts g = 2/N (eq. sigma_phi^2 = 2 sigma^2 / (N B^2)); unequal shifts give more.
    The phase variance depends on phi for unequal shifts; this is its average over phi.
    """
    P = least_squares_weights(shifts)
    cov = P @ P.T  # (3,3) covariance of [A, C, S] per unit sigma^2
    return float(0.5 * (cov[1, 1] + cov[2, 2]))


def _as_stack(stack, axis: int):
    if isinstance(stack, (list, tuple)):
        if len(stack) == 0:
            raise UnwrapError("empty list of phase-shifted frames")
        if is_torch(stack[0]):
            import torch
            shapes = {tuple(s.shape) for s in stack}
            if len(shapes) != 1:
                raise UnwrapError(f"phase-shifted frames differ in shape: {sorted(shapes)}")
            return torch.stack(list(stack)), 0
        arrays = [np.asarray(s) for s in stack]
        shapes = [a.shape for a in arrays]
        if len(set(shapes)) != 1:
            bad = next(i for i, s in enumerate(shapes) if s != shapes[0])
            raise UnwrapError(f"phase-shifted frame {bad} has shape {shapes[bad]}, frame 0 has "
                              f"{shapes[0]}: all frames must have the same shape")
        return np.stack(arrays), 0
    if not is_torch(stack):
        stack = np.asarray(stack)
        if stack.dtype == object or not (np.issubdtype(stack.dtype, np.number) or stack.dtype == bool):
            raise UnwrapError(f"phase-shift stack has dtype {stack.dtype}: expected numbers")
    if stack.ndim < 1:
        raise UnwrapError("phase-shift stack is a scalar: expected (N, ...) frames")
    return stack, axis


def _default_saturation(dtype):
    if is_torch_dtype(dtype):
        import torch
        if dtype == torch.uint8:
            return 255.0
        return None
    if np.issubdtype(dtype, np.integer):
        return float(np.iinfo(dtype).max)
    return None


def is_torch_dtype(dtype) -> bool:
    return type(dtype).__module__.startswith("torch")


def wrapped_phase(stack, shifts=None, *, axis: int = 0, min_modulation: float = 0.0,
                  saturation="auto", valid_range=None, nonfinite: str = "mask",
                  fill_invalid: bool = True, accumulate: str = "float64",
                  chunk_pixels: int = 32768) -> WrappedPhase:
    """Least-squares wrapped phase, background, modulation and masks of a phase-shift stack.

    ARGUMENTS
    - stack: (N, ...) frames (numpy array of any real dtype, a list of equal-shape frames, or a
      torch tensor); ``axis`` selects the step axis (default 0).
    - shifts: (N,) known shifts delta_n (rad) of ``I_n = A + B cos(phi - delta_n)``; default the
      paper's ``2*pi*n/N``. Unequal shifts are fine (least squares).
    - min_modulation: pixels with ``B < min_modulation`` (input units) are flagged
      ``low_modulation``; B == 0 (phase undefined) is always flagged.
    - saturation: intensity at or above which a frame is saturated; "auto" = the integer dtype's
      maximum (255 for uint8), none for float input; None disables.
    - valid_range: optional (lo, hi): frames outside it are ``out_of_range``.
    - nonfinite: "mask" (NaN/inf pixels are ``out_of_range``, phase NaN) or "raise".
    - fill_invalid: put NaN into ``phase`` where not valid (default).
    - accumulate: "float64" (default) or "float32" (numpy only: the step sums in float32; for
      8/16-bit input with N <= 64 the phase error this adds is below 1e-6 rad, three orders
      under 8-bit quantisation noise; phase, A and B are still returned in float64).

    RETURNED VALUE: :class:`WrappedPhase`.
    """
    stack, axis = _as_stack(stack, axis)
    torch_in = is_torch(stack)
    ndim = stack.ndim if not torch_in else stack.dim()
    if not -ndim <= axis < ndim:
        raise UnwrapError(f"axis {axis} out of range for a stack of shape {tuple(stack.shape)}")
    N = stack.shape[axis]
    if shifts is None:
        if N < 3:
            raise UnwrapError(f"stack has {N} frames along axis {axis} (shape {tuple(stack.shape)}): "
                              "N-step phase shifting needs N >= 3")
        shifts = equal_shifts(N)
    shifts = np.asarray(shifts, dtype=np.float64).reshape(-1)
    if shifts.size != N:
        raise UnwrapError(f"stack has {N} frames along axis {axis} (shape {tuple(stack.shape)}) but "
                          f"{shifts.size} phase shifts were given: they must match")
    if nonfinite not in ("mask", "raise"):
        raise UnwrapError(f"nonfinite must be 'mask' or 'raise', got {nonfinite!r}")
    if accumulate not in ("float64", "float32"):
        raise UnwrapError(f"accumulate must be 'float64' or 'float32', got {accumulate!r}")
    P = least_squares_weights(shifts)
    if saturation == "auto":
        saturation = _default_saturation(stack.dtype)
    if torch_in:
        return _wrapped_phase_torch(stack, axis, P, min_modulation, saturation, valid_range,
                                    nonfinite, fill_invalid)
    return _wrapped_phase_numpy(np.moveaxis(stack, axis, 0), P, min_modulation, saturation,
                                valid_range, nonfinite, fill_invalid, accumulate, chunk_pixels)


def _frame_masks(flat, saturation, valid_range, xp_any, xp_all, isfinite):
    out = None
    if flat.dtype.kind == "f":
        out = ~xp_all(isfinite(flat))
    sat = xp_any(flat >= saturation) if saturation is not None else None
    if valid_range is not None:
        lo, hi = valid_range
        rng = xp_any((flat < lo) | (flat > hi))
        out = rng if out is None else (out | rng)
    return sat, out


def _finish(xp, C, S, A, min_modulation, saturated, out_of_range, fill_invalid):
    """Phase, B and masks from the fitted [A, C, S] (shared by both backends)."""
    B_raw = xp.hypot(C, S)
    # below 1e-9 of the background the fit's rounding dominates: B is zero, the phase undefined
    defined = B_raw > 1e-9 * xp.abs(A)
    defined = defined & (B_raw > 0)
    if out_of_range is not None:
        defined = defined & ~out_of_range
    C_safe = xp.where(defined, C, 1.0 + 0.0 * C)  # keeps atan2/hypot gradients finite
    S_safe = xp.where(defined, S, 0.0 * S)
    phase = xp.atan2(S_safe, C_safe)
    B = xp.where(defined, xp.hypot(C_safe, S_safe), 0.0 * C)
    low = ~defined
    if min_modulation:
        low = low | (B < min_modulation)
    if out_of_range is not None:
        low = low & ~out_of_range
    valid = ~low
    if saturated is not None:
        valid = valid & ~saturated
    if out_of_range is not None:
        valid = valid & ~out_of_range
    if fill_invalid:
        phase = xp.where(valid, phase, math.nan + 0.0 * phase)
    return phase, B, low, valid


def _wrapped_phase_numpy(stack, P, min_modulation, saturation, valid_range, nonfinite,
                         fill_invalid, accumulate, chunk_pixels):
    N = stack.shape[0]
    pix_shape = stack.shape[1:]
    flat = np.ascontiguousarray(stack).reshape(N, -1)
    if flat.dtype.kind == "f" and nonfinite == "raise" and not np.all(np.isfinite(flat)):
        n_bad = int((~np.isfinite(flat)).any(axis=0).sum())
        raise UnwrapError(f"phase-shift stack holds NaN/inf at {n_bad} pixel(s)")
    if flat.dtype.kind not in "uif" and flat.dtype != bool:
        raise UnwrapError(f"phase-shift stack has dtype {flat.dtype}: expected real numbers")
    acc = np.float32 if accumulate == "float32" else np.float64
    Pw = P.astype(acc)
    n_pix = flat.shape[1]
    coef = np.empty((3, n_pix), dtype=np.float64)
    step = max(1024, int(chunk_pixels))
    for s in range(0, n_pix, step):  # chunks keep the converted block in cache
        block = flat[:, s:s + step].astype(acc, copy=False)
        if flat.dtype.kind == "f":
            block = np.where(np.isfinite(block), block, 0.0)
        coef[:, s:s + step] = Pw @ block
    saturated, out_of_range = _frame_masks(flat, saturation, valid_range,
                                           lambda m: m.any(axis=0), lambda m: m.all(axis=0),
                                           np.isfinite)
    A, C, S = coef[0], coef[1], coef[2]
    # numpy fast path of _finish (same rules, no gradient bookkeeping): one atan2, one sqrt
    B = np.sqrt(C * C + S * S)
    defined = (B > 1e-9 * np.abs(A)) & (B > 0)
    phase = np.arctan2(S, C)
    low = ~defined
    if min_modulation:
        low |= B < min_modulation
    valid = ~low
    if out_of_range is not None:
        low &= ~out_of_range
        valid &= ~out_of_range
        B[out_of_range] = 0.0
    if saturated is not None:
        valid &= ~saturated
    B[~defined] = 0.0
    if fill_invalid:
        phase[~valid] = np.nan
    zeros = np.zeros(n_pix, dtype=bool)
    r = lambda x: np.asarray(x).reshape(pix_shape)  # noqa: E731
    return WrappedPhase(r(phase), r(A), r(B), r(low),
                        r(saturated if saturated is not None else zeros),
                        r(out_of_range if out_of_range is not None else zeros), r(valid))


def _wrapped_phase_torch(stack, axis, P, min_modulation, saturation, valid_range, nonfinite,
                         fill_invalid):
    import torch
    stack = torch.movedim(stack, axis, 0)
    N = stack.shape[0]
    pix_shape = tuple(stack.shape[1:])
    flat = stack.reshape(N, -1)
    floating = flat.is_floating_point()
    x = flat.to(torch.float64)
    with torch.no_grad():
        finite = torch.isfinite(x)
        out_of_range = None
        if floating:
            if nonfinite == "raise" and not bool(finite.all()):
                n_bad = int((~finite).any(dim=0).sum())
                raise UnwrapError(f"phase-shift stack holds NaN/inf at {n_bad} pixel(s)")
            out_of_range = ~finite.all(dim=0)
        saturated = (x >= saturation).any(dim=0) if saturation is not None else None
        if valid_range is not None:
            lo, hi = valid_range
            rng = ((x < lo) | (x > hi)).any(dim=0)
            out_of_range = rng if out_of_range is None else out_of_range | rng
    if floating:
        x = torch.where(finite, x, torch.zeros_like(x))
    Pt = torch.as_tensor(np.array(P), dtype=torch.float64, device=x.device)
    coef = Pt @ x
    A, C, S = coef[0], coef[1], coef[2]
    xp = namespace(x)
    phase, B, low, valid = _finish(xp, C, S, A, min_modulation, saturated, out_of_range,
                                   fill_invalid)
    zeros = torch.zeros(flat.shape[1], dtype=torch.bool, device=x.device)
    r = lambda t: t.reshape(pix_shape)  # noqa: E731
    return WrappedPhase(r(phase), r(A), r(B), r(low),
                        r(saturated if saturated is not None else zeros),
                        r(out_of_range if out_of_range is not None else zeros), r(valid))
