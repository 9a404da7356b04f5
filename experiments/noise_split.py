"""Where the plane estimator's phase noise comes from, on a twin render (which knows its truth).

:func:`experiments.learned_parity.capture_noise` measures phase noise as the robust spread of the
residual of the traditional absolute phase ``Phi = phi + 2 pi k`` from a 5x5 plane. On a twin
render, the projector coordinate of each pixel is known, so that spread splits into:

- ``true``: the rendered phase's error from the exact phase, ``wrap(phi - 2 pi f u_p / W)`` (the
  sensor noise and any renderer bias, no estimator);
- ``geometry``: the same plane residual of the *exact* phase (the surface's curvature and
  grazing geometry inside the window, no noise);
- ``plane`` and ``plane_raw``: the estimator with and without the order-outlier correction of
  :func:`experiments.plane_residual.order_outlier_residual` (``raw``: a neighbour with a wrong
  order moves the plane by ~2 pi / 25).

Each per decile of the high frequency's modulation B (full scale), with the error rate of the
traditional orders there. All spreads are 1.4826 x median |.| (rad); the plane's corrected for
its degrees of freedom as :func:`unwrap.reliability.plane_residual_noise` does.
"""
from __future__ import annotations

import math

import numpy as np

from .errors import ExperimentError


def phase_error_split(path, pair=(1.0, 16.0), orientation: str = "v", bins: int = 10) -> dict:
    """The split of the module docstring on every sample of a twin file ``path`` (it must hold the
    projector coordinate). RETURNED VALUE: {"B": [median per decile], "plane", "plane_raw", "true",
    "geometry", "wrong_pct": [per decile], "pixels"}."""
    import json

    import h5py
    import torch

    from unwrap.dataset import FringeOrderDataset
    from unwrap.learned.smoothing import smooth_phase
    from unwrap.reliability import plane_centre_dof

    from .plane_residual import order_outlier_residual

    with h5py.File(path, "r") as h5:
        if f"{orientation}/coordinate" not in h5:
            raise ExperimentError(f"{path}: no {orientation}/coordinate (a twin render knows its truth; a capture does not)")
        width = float(json.loads(h5.attrs["widths"])[orientation])
        coords = h5[f"{orientation}/coordinate"][()]
    ds = FringeOrderDataset(path, method="mf", frequencies=tuple(pair), orientation=orientation, crop=None, seed=0)
    dof = plane_centre_dof(5)
    cols = {k: [] for k in ("B", "plane", "plane_raw", "true", "geometry", "wrong")}
    for i in range(len(ds)):
        it = ds[i]
        ok = (it["valid"] & (it["order_traditional"] >= 0)).numpy()
        u = coords[i].astype(np.float64)
        okt = ok & np.isfinite(u)
        Pt = 2 * math.pi * pair[1] * np.where(okt, u, 0.0) / width
        phi = it["phase_high"][0].double().numpy()
        Phi = phi + 2 * math.pi * it["order_traditional"].double().numpy()
        tok = torch.from_numpy(ok)
        raw = Phi - smooth_phase(torch.from_numpy(Phi)[None, None], tok[None, None], 5, "plane")[0, 0].numpy()
        fixed = order_outlier_residual(torch.from_numpy(Phi), tok).numpy()
        geom = Pt - smooth_phase(torch.from_numpy(Pt)[None, None], torch.from_numpy(okt)[None, None], 5,
                                 "plane")[0, 0].numpy()
        interior = okt & (torch.nn.functional.avg_pool2d(torch.from_numpy(okt)[None, None].double(), 5, 1, 2)[0, 0]
                          .numpy() > 0.999)
        lab = it["order_true"].numpy() >= 0
        cols["B"].append(it["modulation_high"][0].double().numpy()[interior])
        cols["plane"].append(fixed[interior])
        cols["plane_raw"].append(raw[interior])
        cols["true"].append(np.angle(np.exp(1j * (phi - Pt)))[interior])
        cols["geometry"].append(geom[interior])
        cols["wrong"].append((lab & (it["order_traditional"].numpy() != it["order_true"].numpy()))[interior])
    if not cols["B"]:
        raise ExperimentError(f"{path}: no samples")
    c = {k: np.concatenate(v) for k, v in cols.items()}
    edges = np.quantile(c["B"], np.linspace(0.0, 1.0, bins + 1))
    out = {k: [] for k in ("B", "plane", "plane_raw", "true", "geometry", "wrong_pct")}
    rs = lambda x: float(1.4826 * np.median(np.abs(x)))  # noqa: E731
    for lo, hi in zip(edges[:-1], edges[1:]):
        s = (c["B"] >= lo) & (c["B"] <= hi)
        if s.sum() < 100:
            continue
        out["B"].append(float(np.median(c["B"][s])))
        for k in ("plane", "plane_raw", "geometry"):
            out[k].append(rs(c[k][s]) * dof)
        out["true"].append(rs(c["true"][s]))
        out["wrong_pct"].append(float(100 * c["wrong"][s].mean()))
    out["pixels"] = int(c["B"].size)
    return out
