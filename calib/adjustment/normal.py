"""Normal equations of the bundle adjustment, reduced on the global parameters (Schur complement).

The Jacobian of the adjustment has an arrow structure: every residual row depends on the global
parameters (intrinsics, distortion, rig, warp: G columns) and on one pose block (6 columns). With
the rows laid out padded per pose block, ``(S, R)`` rows for S blocks, the normal matrix is

    [ U    W ]      U = Jg^T Jg (G, G),  W_s = Jg_s^T Jv_s (G, 6),  V_s = Jv_s^T Jv_s (6, 6)
    [ W^T  V ]      V block-diagonal

and a (damped) Gauss-Newton step solves it by eliminating the poses: ``S = U - sum_s W_s V_s^-1
W_s^T`` (G, G), one Cholesky of S, then each pose's step from its own 6x6 block. Forming and solving
cost time and memory linear in S (as COLMAP/Ceres's Schur solvers; mrcal uses a sparse Cholesky).
The covariance of the globals is ``S^-1`` and that of pose s is ``V_s^-1 + Y_s^T S^-1 Y_s`` with
``Y_s = W_s V_s^-1``: the same factorisation.

Everything is Jacobi-scaled (each column divided by its norm) before damping and factorising, so
Levenberg-Marquardt's damping ``lam * diag(J^T J)`` is ``lam * I`` here. ``plus_second_order``
adds the residuals' second-order term (same block pattern) for Newton steps; ``solve(low_rank=)``
subtracts a few dense rank-one terms by the Woodbury identity (the device noise estimated jointly,
``calib.adjustment.solver``) without giving up the block structure.

SYNOPSIS

    >>> import numpy as np
    >>> from calib.adjustment.normal import NormalEquations
    >>> rng = np.random.default_rng(0)
    >>> Jg, Jv, r = rng.normal(size=(40, 3)), rng.normal(size=(40, 6)), rng.normal(size=40)
    >>> step = NormalEquations(Jg, Jv, r, n_slots=2).solve(0.0)
    >>> J = np.zeros((40, 15)); J[:, :3] = Jg; J[:20, 3:9] = Jv[:20]; J[20:, 9:] = Jv[20:]
    >>> full = np.linalg.lstsq(J, -r, rcond=None)[0]
    >>> bool(np.allclose(np.r_[step.dg, step.dv.ravel()], full))
    True
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _spd_inverse(V: np.ndarray) -> np.ndarray:
    """Inverses of a stack of symmetric positive definite matrices (..., n, n); LinAlgError where
    one is not positive definite (Cholesky decides)."""
    np.linalg.cholesky(V)
    return np.linalg.inv(V)


class SingularNormalEquations(np.linalg.LinAlgError):
    """The (damped) normal matrix is not positive definite."""


@dataclass
class Step:
    """A step: dg (G,) globals, dv (S, 6) poses; predicted cost decrease (model) and the
    directional derivative of the cost along the step, ``2 (J^T r) . d`` (negative)."""

    dg: np.ndarray
    dv: np.ndarray
    predicted: float
    slope: float


class NormalEquations:
    """``J^T J`` and ``J^T r`` of one linearisation, Jacobi-scaled.

    ARGUMENTS
    - Jg (rows, G), Jv (rows, 6), r (rows,): rows padded per pose block, S * R rows in block order.
    - n_slots: S.
    - row_groups: optional list of boolean row masks; ``parts`` then holds each group's share of
      ``J^T r`` (scaled), for ``solve``'s low-rank term.
    """

    def __init__(self, Jg: np.ndarray, Jv: np.ndarray, r: np.ndarray, n_slots: int, row_groups=()):
        S = int(n_slots)
        G = Jg.shape[1]
        Jg3 = Jg.reshape(S, -1, G)
        Jv3 = Jv.reshape(S, -1, 6)
        Jv3t = Jv3.transpose(0, 2, 1)
        Jg3t = Jg3.transpose(0, 2, 1)
        r3 = r.reshape(S, -1, 1)
        # per-block products summed: small single-threaded BLAS calls, no large threaded gemm (a
        # multi-threaded BLAS stalls on a machine whose cores are busy)
        U = np.matmul(Jg3t, Jg3).sum(axis=0)
        W = np.matmul(Jg3t, Jv3)
        V = np.matmul(Jv3t, Jv3)
        bg = np.matmul(Jg3t, r3).sum(axis=0)[:, 0]
        bv = np.matmul(Jv3t, r3)[..., 0]
        self.col_norm_g = np.sqrt(np.diag(U).copy())
        self.col_norm_v = np.sqrt(np.einsum("sii->si", V))
        sg = 1.0 / np.where(self.col_norm_g > 0, self.col_norm_g, 1.0)
        sv = 1.0 / np.where(self.col_norm_v > 0, self.col_norm_v, 1.0)
        self.scale_g, self.scale_v = sg, sv
        self.U = U * sg[:, None] * sg[None, :]
        self.W = W * sg[None, :, None] * sv[:, None, :]
        self.V = V * sv[:, :, None] * sv[:, None, :]
        self.bg = bg * sg
        self.bv = bv * sv
        self.cost = float(r @ r)
        self._factor = None
        self.parts = []
        for mask in row_groups:
            rm = (r * mask).reshape(S, -1, 1)
            self.parts.append((np.matmul(Jg3t, rm).sum(axis=0)[:, 0] * sg, np.matmul(Jv3t, rm)[..., 0] * sv))

    def plus_second_order(self, U2: np.ndarray, W2: np.ndarray, V2: np.ndarray) -> "NormalEquations":
        """Newton's equations: these Gauss-Newton ones plus the second-order term of the residuals,
        ``sum_i r_i d2r_i`` in blocks U2 (G, G), W2 (S, G, 6), V2 (S, 6, 6) (unscaled); same scaling."""
        sg, sv = self.scale_g, self.scale_v
        out = object.__new__(NormalEquations)
        out.__dict__.update(self.__dict__)
        out.U = self.U + U2 * sg[:, None] * sg[None, :]
        out.W = self.W + W2 * sg[None, :, None] * sv[:, None, :]
        out.V = self.V + V2 * sv[:, :, None] * sv[:, None, :]
        out._factor = None
        return out

    def _reduce(self, lam: float):
        """(Schur complement S, S^-1, V^-1, Y = W V^-1) with damping ``lam``."""
        eye6 = np.eye(6)
        Vd = self.V + lam * eye6
        try:
            Vinv = _spd_inverse(Vd)
        except np.linalg.LinAlgError:
            raise SingularNormalEquations("a pose block of the normal matrix is singular") from None
        Y = np.matmul(self.W, Vinv)
        Sm = self.U + lam * np.eye(len(self.U)) - np.matmul(Y, self.W.transpose(0, 2, 1)).sum(axis=0)
        Sm = 0.5 * (Sm + Sm.T)
        try:
            Sinv = _spd_inverse(Sm[None])[0] if len(Sm) else np.zeros((0, 0))
        except np.linalg.LinAlgError:
            raise SingularNormalEquations("the reduced normal matrix of the global parameters is "
                                          "singular") from None
        return Sm, Sinv, Vinv, Y

    def _apply_inverse(self, factor, bg, bv):
        """(H + lam I)^-1 [bg; bv] (scaled) from a factorisation of ``_reduce``."""
        _, Sinv, Vinv, Y = factor
        xg = Sinv @ (bg - np.matmul(Y, bv[..., None]).sum(axis=0)[:, 0])
        xv = np.matmul(Vinv, (bv - np.einsum("sgi,g->si", self.W, xg))[..., None])[..., 0]
        return xg, xv

    def solve(self, lam: float, low_rank=None) -> Step:
        """Step minimising ``|r + J d|^2 + lam |D d|^2`` (D: column norms); raises
        SingularNormalEquations where the damped matrix is not positive definite.

        ``low_rank``: coefficients ``c`` (one per ``row_groups`` entry): the matrix becomes
        ``H - sum_k c_k p_k p_k^T`` with ``p_k`` the groups' shares of ``J^T r`` (Woodbury; two
        extra solves with the same factorisation). SingularNormalEquations where that is not
        positive definite."""
        factor = self._reduce(lam)
        if lam == 0.0:
            self._factor = factor
        xg, xv = self._apply_inverse(factor, self.bg, self.bv)
        if low_rank is not None:
            Z = [self._apply_inverse(factor, pg, pv) for pg, pv in self.parts]
            BtZ = np.array([[pg @ zg + np.sum(pv * zv) for zg, zv in Z] for pg, pv in self.parts])
            K = np.diag(1.0 / np.asarray(low_rank, float)) - 0.5 * (BtZ + BtZ.T)
            if np.linalg.eigvalsh(K)[0] <= 0:
                raise SingularNormalEquations("the low-rank corrected matrix is not positive definite")
            Btu = np.array([pg @ xg + np.sum(pv * xv) for pg, pv in self.parts])
            coef = np.linalg.solve(K, Btu)
            xg = xg + sum(c * zg for c, (zg, _) in zip(coef, Z))
            xv = xv + sum(c * zv for c, (_, zv) in zip(coef, Z))
        xg, xv = -xg, -xv
        bx = float(self.bg @ xg + np.sum(self.bv * xv))
        predicted = -bx + lam * float(xg @ xg + np.sum(xv * xv))
        return Step(xg * self.scale_g, xv * self.scale_v, predicted, 2.0 * bx)

    def covariance(self):
        """Undamped ``(J^T J)^-1`` blocks: (globals (G, G), poses (S, 6, 6)), unit residual variance."""
        _, Sinv, Vinv, Y = self._factor if self._factor is not None else self._reduce(0.0)
        Sinv = 0.5 * (Sinv + Sinv.T)
        cov_v = Vinv + np.matmul(np.matmul(Y.transpose(0, 2, 1), Sinv), Y)
        sg, sv = self.scale_g, self.scale_v
        return Sinv * sg[:, None] * sg[None, :], cov_v * sv[:, :, None] * sv[:, None, :]

    def weakest_direction(self):
        """(global part (G,), pose index or None): the scaled parameter combination the undamped
        matrix determines worst (also where it is singular): the worst-conditioned pose block if
        that is singular or worse than the reduced matrix, else the eigenvector of the smallest
        eigenvalue of the reduced matrix."""
        G = len(self.U)
        evv = np.linalg.eigvalsh(self.V)
        ratio_v = evv[:, 0] / np.maximum(evv[:, -1], 1e-300)
        worst = int(np.argmin(ratio_v))
        if ratio_v[worst] < 1e-15 or G == 0:
            return np.zeros(G), worst
        Y = np.matmul(self.W, _spd_inverse(self.V))
        Sm = self.U - np.matmul(Y, self.W.transpose(0, 2, 1)).sum(axis=0)
        ev, vec = np.linalg.eigh(0.5 * (Sm + Sm.T))
        if ev[0] / max(ev[-1], 1e-300) <= ratio_v[worst]:
            return vec[:, 0], None
        return np.zeros(G), worst

    def conditioning(self) -> dict:
        """Condition numbers of the scaled reduced matrix S and the worst pose block (undamped)."""
        Sm = (self._factor if self._factor is not None else self._reduce(0.0))[0]
        ev = np.linalg.eigvalsh(Sm) if len(Sm) else np.ones(1)
        evv = np.linalg.eigvalsh(self.V)
        unscaled = np.linalg.eigvalsh(Sm / (self.scale_g[:, None] * self.scale_g[None, :])) if len(Sm) \
            else np.ones(1)
        return {"reduced_scaled": float(ev[-1] / ev[0]), "reduced_unscaled": float(unscaled[-1] / unscaled[0]),
                "pose_blocks_worst": float(np.max(evv[:, -1] / evv[:, 0])),
                "normal_matrix_rcond": float(min(ev[0] / ev[-1], np.min(evv[:, 0] / evv[:, -1])))}
