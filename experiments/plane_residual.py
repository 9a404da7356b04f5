"""The residual of an absolute phase from its local plane, robust to the neighbours' order errors
(the plane estimator of :func:`experiments.learned_parity.capture_noise`)."""
from __future__ import annotations

import math

import torch


def order_outlier_residual(Phi, ok, window: int = 5, passes: int = 1):
    """Residual (H, W) float64 of an absolute phase ``Phi`` (H, W) tensor, rad, from the plane
    through its ``window`` x ``window`` neighbours among ``ok`` (H, W) bool, after ``passes``
    corrections of order outliers (:func:`order_outlier_fit`'s residual)."""
    return order_outlier_fit(Phi, ok, window, passes)[1]


def order_outlier_fit(Phi, ok, window: int = 5, passes: int = 1):
    """(Phi moved (H, W) float64 rad, its residual (H, W) rad from the plane): ``Phi`` (H, W) tensor
    rad with its order outliers moved by their whole turns, ``passes`` times, and the residual of
    the moved phase from the plane through its ``window`` x ``window`` neighbours among ``ok``
    (H, W) bool; the plane itself is ``moved - residual`` (with ``Phi - residual`` a pixel whose
    order was moved keeps its whole turns).

    A pixel whose traditional order is wrong sits ~2 pi off the plane; left in, it moves the plane
    of each of its 24 neighbours by ~2 pi / 25 = 0.25 rad, so where orders fail often (dim pixels:
    at 6 % wrong, 77 % of the pixels have a wrong neighbour) the robust spread of the residuals
    measures the order errors, not the noise (3.3x at the skull twin's dimmest decile, docs/learned.md).
    Each pass moves every pixel by the whole turns of its residual, ``Phi - 2 pi round(r / 2 pi)``,
    and refits; a pixel's own noise (<< pi) is untouched."""
    from unwrap.learned.smoothing import smooth_phase

    Phi = Phi.double()
    v = ok[None, None]
    r = Phi - smooth_phase(Phi[None, None], v, window, "plane")[0, 0]
    for _ in range(int(passes)):
        Phi = Phi - 2 * math.pi * torch.round(torch.where(ok, r, torch.zeros_like(r)) / (2 * math.pi))
        r = Phi - smooth_phase(Phi[None, None], v, window, "plane")[0, 0]
    return Phi, r
