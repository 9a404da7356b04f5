"""How far to trust sigmas that rest on a few poses: the inflation for uncertain per-pose error levels.

The per-pose error model (:mod:`calib.uncertainty.pose_error_model`) gives every global parameter j the variance

    v_j = a_j + sum_l b_jl,   a_j = s0 B_jj,   b_jl = S_l |(B J^T A_l)_j|^2,

where ``S_l`` is the estimated variance of field l's per-pose coefficient. Each ``S_l`` is
estimated from one coefficient per pose: with 5 poses it rests on a handful of numbers, so ``v_j``
is itself a random estimate, too small about as often as too large. A shift ``d`` of the estimate
(what leaving a pose out, or a new session, shows) divided by the reported sigma then scatters
more than a unit Gaussian: ``d`` and the residuals are independent (for Gaussian errors in a
linearised fit, ``theta - theta_true = B J^T e`` and ``r = (I - H) e`` are uncorrelated), so

    E[d^2 / v_hat] = E[d^2] E[1 / v_hat] = v E[1 / v_hat] > 1   (Jensen),

the Student-t effect of a variance estimated with few degrees of freedom. The reported variance is
therefore multiplied by

    f_j = E[v_j / v_hat_j],   v_hat_j = a_j + sum_l b_jl X_l,   X_l ~ chi2(nu_l) / nu_l,

so that ``E[d^2 / (f_j v_hat_j)] = 1``. ``nu_l`` is field l's effective degrees of freedom: those
of its statistic ``T_l = |A_l^T r|^2``, a quadratic form in Gaussian errors with ``E T_l = tr C_l``,
``Var T_l = 2 tr(C_l^2)``, ``C_l = A_l^T (I - H) Omega (I - H) A_l`` (n_poses x n_poses), so
``T_l ~ tr(C_l) chi2(nu_l) / nu_l`` with ``nu_l = tr(C_l)^2 / tr(C_l^2)`` (Satterthwaite): at most the
number of poses, fewer where the fit absorbs part of the field or a few poses dominate it. ``S_hat_l``
is taken to scatter as ``T_l`` does (a kept field stands 3.5 standard deviations above the
independent errors' share of ``T_l``, so that share changes little). The independent part
``a_j`` rests on thousands of residuals and is taken as exact. ``f_j`` is computed by Monte Carlo
(fixed seed, 4000 draws: deterministic, < 1 ms) at the estimated ``S_l``; it tends to 1 as the
poses grow (``nu_l`` grows with them) and is exactly 1 where no field is kept. With one dominant
field it is ``nu / (nu - 2)`` (the t distribution's variance), which is infinite for ``nu <= 2``;
the independent part keeps ``f_j`` finite but large there.

The effective degrees of freedom of ``v_hat_j`` (Welch-Satterthwaite, ``v_j^2 / sum_l b_jl^2 / nu_l``)
say how well the sigma itself is known (relative standard deviation ``~ 1 / sqrt(2 nu)``); below
``MIN_DOF`` (the sigma uncertain by more than a third, the variance inflation then ``>~ 2``) the session is too
small to trust its own sigmas, which :mod:`calib.uncertainty.assess` says in the run's warnings and in
``calibration.json``. Measured (docs/calib.md, "Honest uncertainty"): nested leave-one-pose-out
shifts over the reported sigma on the SLStudio session and on rendered sessions of 4-6 poses.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_DOF = 4.5
"""Effective degrees of freedom of a parameter's variance below which the session is too small to
trust its own sigmas (relative sd of the sigma ``1 / sqrt(2 nu)`` > 1/3)."""

DRAWS = 4000


@dataclass
class LevelUncertainty:
    """Per global parameter (arrays aligned with the error model's names): ``inflation`` (sigma
    multiplier, sqrt(f_j) >= 1), ``dof`` (effective degrees of freedom of its variance, inf where
    no field contributes); ``field_dof``: {field label: nu_l} of the fields kept."""

    inflation: np.ndarray
    dof: np.ndarray
    field_dof: dict


def level_uncertainty(S, s0, cross, lever, B, g, labels, *, seed: int = 0) -> LevelUncertainty:
    """The inflation and degrees of freedom (module docstring) of the global parameters ``g``
    (indices into the adjustment's parameters). ``S`` (L,): field variances (0: not kept); ``s0``:
    independent variance; ``cross[l][k]`` = ``A_l^T (I - H) A_k`` (n_poses, n_poses), the fields'
    matrices seen through the residual projection; ``lever``: per field ``B J^T A_l``; ``B`` =
    (J^T J)^-1."""
    S = np.asarray(S, dtype=np.float64)
    kept = np.flatnonzero(S > 0)
    a = s0 * np.diag(B)[g]
    if not len(kept):
        return LevelUncertainty(np.ones(len(g)), np.full(len(g), np.inf), {})
    nu = np.empty(len(kept))
    for i, l in enumerate(kept):
        # G = (I - H) A_l: G^T G = cross[l][l], G^T A_k = cross[l][k] (I - H symmetric, idempotent)
        C = s0 * cross[l][l] + sum(S[k] * cross[l][k] @ cross[l][k].T for k in kept)
        nu[i] = np.trace(C) ** 2 / max(np.sum(C * C.T), 1e-300)        # tr(C)^2 / tr(C^2)
    b = np.stack([S[l] * np.sum(lever[l][g] ** 2, axis=1) for l in kept], axis=1)   # (G, K)
    v = a + b.sum(axis=1)
    X = np.random.default_rng(seed).chisquare(nu, size=(DRAWS, len(kept))) / nu        # (D, K)
    f = np.mean(v[None, :] / (a[None, :] + X @ b.T), axis=0)
    dof = v ** 2 / np.maximum(np.sum(b ** 2 / nu, axis=1), 1e-300)
    return LevelUncertainty(np.sqrt(np.maximum(f, 1.0)), dof,
                            {labels[l]: float(n) for l, n in zip(kept, nu)})
