"""Reference fringe orders from a redundant MF ladder (e.g. 1 / 4 / 16 periods), to label the
two-frequency subset (unit -> top, e.g. 1 -> 16) of a real capture for fine-tuning.

The ladder decodes the top frequency in small steps (1 -> 4 -> 16: noise and bias of the coarse
phase are multiplied by 4 per step instead of 16 in one jump), so where every step of the ladder
is decided with a margin its order is a trustworthy label for the one-jump pair the network sees.
Only the TOP frequency gets a reference: an intermediate one (4) is decoded from the unit phase in
one step, exactly as the traditional method would, so a label there would be circular.

A pixel is *trusted* (carries a reference) when

- ``valid``: every frequency of the ladder has a usable wrapped phase (the phase-shift flags: not
  low modulation, not saturated, finite);
- ``modulation``: every frequency's modulation is at least ``min_modulation`` (fraction of full
  scale; weak fringes give phases whose noise the margin test below only catches statistically);
- ``consistency``: at every ladder step j the real-valued order ``prior_j = (f_j/f_{j-1} Phi_{j-1}
  - phi_j) / 2 pi`` lies within ``max_step_residual`` periods of an integer (a biased or noisy
  coarse phase shows as a residual near 0.5; 0.2 leaves 0.3 period of margin to the wrong order);
- ``range``: the ladder's top order lies in [0, round(f_top)].

SYNOPSIS

    >>> import numpy as np
    >>> from unwrap.ladder_reference import ladder_reference
    >>> u = np.linspace(0, 911, 64)[None, :]                       # projector column, 912 px wide
    >>> phis = [np.angle(np.exp(2j * np.pi * f * u / 912)) for f in (1, 4, 16)]
    >>> mods = [np.full(u.shape, 0.3)] * 3
    >>> r = ladder_reference(phis, (1, 4, 16), mods, width=912)
    >>> bool(r.trusted.all()), bool((r.order == np.floor(16 * u / 912 + 0.5)).all())
    (True, True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import UnwrapError
from .temporal import check_mf_ladder, mf_unwrap

TWO_PI = 2 * math.pi


@dataclass
class LadderReference:
    """Reference of the top frequency of a ladder; arrays (H, W).

    order: int64 order of the top frequency, -1 where not trusted; trusted: bool;
    per_period: absolute phase of the top frequency divided by f_top (rad per period, NaN where
    not trusted): ``Phi_ref f / f_top`` for any frequency f; step_residual: (n_steps, H, W) float64
    |prior - round(prior)| per ladder step (periods of that step's frequency, NaN where invalid);
    excluded: pixels removed per reason (in this order, each counted once: invalid, modulation,
    consistency, range)."""
    order: np.ndarray
    trusted: np.ndarray
    per_period: np.ndarray
    step_residual: np.ndarray
    excluded: dict


def check_redundant_ladder(frequencies) -> np.ndarray:
    """An MF ladder of three or more frequencies (unit first); UnwrapError otherwise (two
    frequencies carry no redundancy: the reference would be the traditional decode itself)."""
    f = np.asarray(frequencies, dtype=np.float64).reshape(-1)
    if f.size < 3:
        raise UnwrapError(f"ladder reference needs three or more MF frequencies (e.g. 1, 4, 16), got "
                          f"{[float(x) for x in f]}: two frequencies have no redundancy to label their own pair")
    return check_mf_ladder(np.sort(f))


def ladder_reference(phases, frequencies, modulations, *, width=None, valid=None, min_modulation: float = 0.02,
                     max_step_residual: float = 0.2) -> LadderReference:
    """Trusted reference order of the ladder's top frequency (module docstring).

    ARGUMENTS
    - phases: wrapped phases (rad), one (H, W) array per frequency, NaN where unusable;
    - frequencies: the ladder (periods across the pattern), increasing, the first <= 1;
    - modulations: modulation B per frequency as a fraction of full scale, (H, W) each;
    - width: projector pixels across the fringes (places the unit phase's cut as ``calib unwrap``);
    - valid: optional extra (H, W) bool mask; min_modulation, max_step_residual: see the module.
    """
    f = check_redundant_ladder(frequencies)
    if list(f) != [float(x) for x in frequencies]:
        raise UnwrapError(f"ladder frequencies must be given increasing, got {list(frequencies)}")
    if not 0 < max_step_residual < 0.5:
        raise UnwrapError(f"max_step_residual = {max_step_residual}: expected 0 < value < 0.5 period")
    phis = [np.asarray(p, dtype=np.float64) for p in phases]
    ok = np.all([np.isfinite(p) for p in phis], axis=0)
    if valid is not None:
        ok &= np.asarray(valid, dtype=bool)
    r = mf_unwrap([np.nan_to_num(p) for p in phis], f, width=width, valid=ok)
    res = np.stack([np.where(ok, np.abs(prior - np.rint(prior)), np.nan) for _, prior, _ in r.levels])
    mod_ok = np.all([np.asarray(m, dtype=np.float64) >= min_modulation for m in modulations], axis=0)
    consistent = np.all(np.nan_to_num(res, nan=1.0) <= max_step_residual, axis=0)
    k_top = np.rint(np.asarray(r.levels[-1][1], dtype=np.float64))
    in_range = (k_top >= 0) & (k_top <= math.floor(f[-1] + 0.5))
    excluded, left = {}, np.ones(ok.shape, bool)
    for name, keep in (("invalid", ok), ("modulation", mod_ok), ("consistency", consistent), ("range", in_range)):
        excluded[name] = int((left & ~keep).sum())
        left &= keep
    order = np.where(left, k_top, -1).astype(np.int64)
    per_period = np.where(left, (phis[-1] + TWO_PI * k_top) / f[-1], np.nan)
    return LadderReference(order, left, per_period, res, excluded)
