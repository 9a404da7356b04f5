"""Gray code and complementary Gray code combined with phase shifting.

Bits come MSB first as a (n_bits, ...) stack. A reflected Gray code of n bits splits the pattern
into 2**n blocks; ``gray_to_index`` turns bits into the block index c.

Three decoders, each returning :class:`unwrap.temporal.Unwrapped` (prior = the real-valued
fringe-order estimate whose Round[] is k):

- :func:`gray_unwrap`: block = one fringe period, phase 0 at the block start (DESIGN.md
  convention). k = c where phi >= 0 and c + 1 where phi < 0 (the wrap of phi sits mid-block, where
  the code is reliable). Code errors at block edges (phi near 0) are not correctable: no margin.
- :func:`complementary_gray_unwrap`: adds one bit at half-period resolution (the code of
  SLMaster's "SinusCompleGrayCode"); k uses whichever code is far from its own transition, so a
  code edge misplaced by less than a quarter period does no harm.
- :func:`gray_coarse_unwrap`: blocks smaller than the first fringe period (e.g. kamino410's
  100 px blocks with a 200 px beat): the block centre is a coarse coordinate refined by an MF
  ladder of wrapped phases; margin (period - block)/2 px.
- :func:`gray_code_unwrap`: Gray code alone (no phase shifting): the projector coordinate is the
  centre of the decoded block, a map quantised to the block size.
"""
from __future__ import annotations

import math

import numpy as np

from ._xp import TWO_PI, namespace

_NS = namespace(np.zeros(1))
from .errors import UnwrapError
from .temporal import Unwrapped, finish_unwrapped, refine  # noqa: F401  (Unwrapped: re-exported)


def binarize(frames, inverse=None, *, threshold=None, min_contrast: float = 0.0):
    """Bits (bool) and their reliability from Gray-code frames (n_bits, ...).

    ARGUMENTS: frames = captured code images; inverse = the inverted images (pairs), or threshold =
    an image (or scalar) to compare with (e.g. the phase-shift background A). min_contrast:
    |frame - reference| below it makes the pixel unreliable.
    RETURNED VALUE: (bits (n_bits, ...) bool, reliable (...) bool: every bit clear of min_contrast).
    """
    frames = np.asarray(frames, dtype=np.float64)
    if inverse is not None:
        ref = np.asarray(inverse, dtype=np.float64)
        if ref.shape != frames.shape:
            raise UnwrapError(f"Gray-code inverse frames have shape {ref.shape}, the frames "
                              f"{frames.shape}: they must match")
    elif threshold is not None:
        ref = np.asarray(threshold, dtype=np.float64)
    else:
        raise UnwrapError("binarize needs inverse frames or a threshold image")
    diff = frames - ref
    finite = np.all(np.isfinite(diff), axis=0)
    reliable = finite & np.all(np.abs(diff) > min_contrast, axis=0)
    return diff > 0, reliable


def gray_to_index(bits):
    """Block index of reflected Gray-code bits (n_bits, ...) bool, MSB first -> int64 (...)."""
    bits = np.asarray(bits, dtype=bool)
    if bits.ndim < 1 or bits.shape[0] < 1:
        raise UnwrapError("Gray code needs at least one bit")
    binary = np.zeros(bits.shape[1:], dtype=bool)
    index = np.zeros(bits.shape[1:], dtype=np.int64)
    for b in bits:
        binary = binary ^ b
        index = (index << 1) | binary
    return index


def gray_code_bits(index, n_bits: int):
    """Reflected Gray-code bits (n_bits, ...) bool, MSB first, of block indices (for patterns/tests)."""
    index = np.asarray(index, dtype=np.int64)
    g = index ^ (index >> 1)
    return np.stack([(g >> (n_bits - 1 - j)) & 1 for j in range(n_bits)]).astype(bool)


def _valid(phi, reliable, valid):
    ok = np.isfinite(phi) & reliable
    if valid is not None:
        ok = ok & np.asarray(valid, dtype=bool)
    return ok


def gray_unwrap(phi, code_index, frequency: float, *, reliable=None, valid=None) -> Unwrapped:
    """Gray code with one block per fringe period (block c spans phase [2 pi c, 2 pi (c+1))).

    ARGUMENTS: phi = wrapped phase (rad) of the pattern with ``frequency`` periods; code_index =
    block index per pixel; reliable/valid = optional masks.
    """
    phi = np.asarray(phi, dtype=np.float64)
    c = np.asarray(code_index, dtype=np.float64)
    if c.shape != phi.shape:
        raise UnwrapError(f"code index shape {c.shape} differs from the phase shape {phi.shape}")
    ok = _valid(phi, True if reliable is None else np.asarray(reliable, bool), valid)
    phi0 = np.where(ok, phi, 0.0)
    phi0 = np.where(np.abs(phi0) < 1e-9, 0.0, phi0)  # the block start (phi = 0) belongs to c
    prior = c + 0.5 - phi0 / TWO_PI
    k = c + (phi0 < 0)
    return finish_unwrapped(_NS, phi0 + TWO_PI * k, k, prior, ok, frequency, "gray", [])


def complementary_gray_unwrap(phi, period_index, half_period_index, frequency: float, *,
                              reliable=None, valid=None) -> Unwrapped:
    """Complementary Gray code: period index K1 = floor(u/P) and half-shifted K2 = floor(u/P + 1/2).

    With phase 0 at the period start, ``k = Round(u/P) = K2`` where |phi| <= pi/2 (K1 is at its
    transition there), ``K1`` where phi > pi/2 and ``K1 + 1`` where phi < -pi/2. ``K2`` comes from
    the n+1-bit Gray index G (half-period blocks) as ``(G + 1) // 2``.
    """
    phi = np.asarray(phi, dtype=np.float64)
    K1 = np.asarray(period_index, dtype=np.float64)
    K2 = np.asarray(half_period_index, dtype=np.float64)
    if not (K1.shape == K2.shape == phi.shape):
        raise UnwrapError(f"code shapes {K1.shape}, {K2.shape} differ from the phase {phi.shape}")
    ok = _valid(phi, True if reliable is None else np.asarray(reliable, bool), valid)
    phi0 = np.where(ok, phi, 0.0)
    middle = np.abs(phi0) <= 0.5 * math.pi
    coarse = np.where(middle, TWO_PI * K2, TWO_PI * (K1 + 0.5))
    prior, k, Phi = refine(coarse, 1.0, phi0)
    return finish_unwrapped(_NS, Phi, k, prior, ok, frequency, "gray", [])


def gray_coarse_unwrap(code_index, block_px: float, width: float, phases, frequencies, *,
                       reliable=None, valid=None) -> Unwrapped:
    """Gray blocks of ``block_px`` as a coarse coordinate, refined by wrapped phases (MF ladder).

    ARGUMENTS: code_index = block index c (block c covers [c*block, (c+1)*block) px); width =
    projector pixels across the fringes; phases/frequencies = wrapped phases (rad) and their
    periods across the pattern, increasing; the first period W/f must exceed ``block_px`` (the
    coarse error is at most block/2, the step tolerates less than half a period).
    """
    f = np.asarray(frequencies, dtype=np.float64).reshape(-1)
    if len(phases) != f.size or f.size < 1:
        raise UnwrapError(f"{len(phases)} phases but {f.size} frequencies")
    if np.any(np.diff(f) <= 0):
        raise UnwrapError(f"frequencies must increase, got {f.tolist()}")
    period0 = width / f[0]
    if not period0 > block_px:
        raise UnwrapError(f"first fringe period {period0:g} px is not longer than the Gray block "
                          f"{block_px:g} px: the block centre cannot select the fringe order")
    phis = [np.asarray(p, dtype=np.float64) for p in phases]
    c = np.asarray(code_index, dtype=np.float64)
    ok = _valid(phis[0], True if reliable is None else np.asarray(reliable, bool), valid)
    for p in phis[1:]:
        ok &= np.isfinite(p)
    phis = [np.where(ok, p, 0.0) for p in phis]
    u_coarse = (c + 0.5) * block_px - 0.5  # pixel centres at integers
    Phi = TWO_PI * f[0] * u_coarse / width
    prior, k, Phi = refine(Phi, 1.0, phis[0])
    levels = [(float(f[0]), prior, k)]
    for i in range(1, f.size):
        prior, k, Phi = refine(Phi, f[i] / f[i - 1], phis[i])
        levels.append((float(f[i]), prior, k))
    return finish_unwrapped(_NS, Phi, k, prior, ok, f[-1], "gray", levels)


def gray_code_unwrap(code_index, block_px: float, width: float, *, reliable=None, valid=None) -> Unwrapped:
    """Gray code alone: the projector coordinate of a pixel is the centre of its decoded block.

    Block c covers projector pixels ``[c b, (c + 1) b)`` (``b = block_px``), centre
    ``u_p = (c + 1/2) b - 1/2`` (pixel centres at integers). It is returned in the phase layout of
    DESIGN.md with one period per block: frequency ``f = width / b``, absolute phase
    ``Phi = 2 pi f u_p / width``, order ``k = c``, prior ``c`` (exact: no phase to round). The map
    is quantised: within a block the true coordinate differs from the centre by up to ``b / 2``
    (uniform, variance ``b^2 / 12``), an error that a local fit of many camera pixels does not
    average away like noise (``calib.detect.marker_phase`` models it). Where ``width`` is not a multiple
    of ``b`` the last block is cut at the pattern's edge and its centre is that of its part inside,
    ``(c b + width - 1) / 2``: like every decoder's, the coordinate lies inside the pattern (the
    range constraint of :func:`unwrap.temporal.finish_unwrapped`). Codes beyond the pattern
    (``c >= ceil(width / b)``) are invalid.
    """
    c = np.asarray(code_index)
    if not np.issubdtype(c.dtype, np.integer):
        raise UnwrapError(f"code_index must hold integers (decoded block indices), got {c.dtype}")
    if not (np.isfinite(block_px) and block_px >= 1 and np.isfinite(width) and width >= block_px):
        raise UnwrapError(f"block_px must be >= 1 and width >= block_px, got {block_px!r}, {width!r}")
    ok = np.ones(c.shape, bool) if reliable is None else np.asarray(reliable, bool).copy()
    if valid is not None:
        ok &= np.asarray(valid, bool)
    ok &= (c >= 0) & (c < math.ceil(width / block_px))
    frequency = width / block_px
    k = np.where(ok, c, 0).astype(np.float64)
    # centre of the part of the block inside the pattern: a last, partial block (width not a
    # multiple of block_px) ends at the pattern's edge, so no coordinate lies outside it
    u_p = 0.5 * (k * block_px + np.minimum((k + 1) * block_px, width) - 1.0)
    Phi = TWO_PI * u_p / block_px
    return finish_unwrapped(_NS, Phi, k, k.copy(), ok, frequency, "gray", [], width=width)
