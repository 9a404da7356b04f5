"""Ground truth of a render: absolute phase and fringe order per orientation and frequency.

For orientation ``v`` (fringes along projector columns) ``Phi = absolute_phase(u_p, f, W_p)``;
for ``h`` it uses ``v_p`` and ``H_p`` (unwrap.patterns). The wrapped phase the N-step formula
returns is ``phi = atan2(sin Phi, cos Phi)`` in (-pi, pi], and the fringe order is
``k = round((Phi - phi) / (2 pi))``, so that ``Phi = phi + 2 pi k`` exactly. Valid pixels are
those lit by the projector (hit, inside its field, facing it, not shadowed).
"""
from __future__ import annotations

import math

import numpy as np
import torch

from unwrap.patterns import absolute_phase


def fringe_frequencies(patterns) -> dict:
    """{orientation: sorted frequencies} of the phase-shift fringes in a sequence."""
    out: dict = {}
    for p in patterns:
        if p.kind == "fringe":
            out.setdefault(p.orientation, set()).add(p.frequency)
    return {o: sorted(fs) for o, fs in out.items()}


def phase_truth(geometry, projector_size, orientation: str, frequency: float):
    """(phase (H,W) float64 NaN where invalid, order (H,W) int32 -1 where invalid, valid (H,W))."""
    W, H = geometry.size
    Wp, Hp = projector_size
    coord, extent = (geometry.u_p, Wp) if orientation == "v" else (geometry.v_p, Hp)
    valid = geometry.lit
    Phi = absolute_phase(torch.where(valid, coord, torch.zeros_like(coord)), frequency, extent)
    wrapped = torch.atan2(torch.sin(Phi), torch.cos(Phi))
    order = torch.round((Phi - wrapped) / (2 * math.pi)).to(torch.int32)
    phase = torch.where(valid, Phi, torch.full_like(Phi, float("nan")))
    order = torch.where(valid, order, torch.full_like(order, -1))
    return phase.reshape(H, W).numpy(), order.reshape(H, W).numpy(), valid.reshape(H, W).numpy()
