"""What the model misses: residuals per pose and over the board, their spatial correlation, and
whether the rejected points scatter (noise) or cluster (a defect the model does not describe).

- **Spatial correlation**: within each pose, the correlation of the residuals of board points one
  grid step apart (both coordinates, per device), ``rho_1``, and the correlogram (correlation vs
  board distance). Independent residuals give ``rho_1`` near 0 (within ``~1/sqrt(pairs)``); a
  flat-board, independent-noise model is then adequate. Flagged when ``rho_1 > 0.2`` and over 3
  standard errors: the adjustment's independent-residual sigmas are too small
  (:mod:`calib.uncertainty.pose_error_model` accounts for it).
- **Rejected points**: for a device with 3 or more rejections, the mean distance on the board from
  each rejected point to the nearest other rejected one (board points of any pose, board frame),
  against the same statistic for as many points drawn at random among the device's points
  (``draws`` draws): p = the fraction of random draws as clustered as the rejections. Flagged when
  p < 0.01 (a corner of the board, one pose, a printing defect), with where they are.
- **Figures** (:func:`plot_residual_diagnostics`): ``residuals_per_pose.png`` (every pose, both
  devices: residual vectors at the observed pixels, magnified; rejected points marked), and
  ``residuals_on_board.png`` (all poses' residuals at their board positions, and the correlogram):
  the views ``mrcal-show-residuals`` gives of a camera calibration.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

CORRELATION_FLAG = 0.2
CLUSTER_P = 0.01
BINS_IN_STEPS = (0.5, 1.5, 2.5, 3.5, 5.0, 7.0, 10.0, 1e9)


@dataclass
class ResidualDiagnostics:
    """- neighbour_correlation: {device: rho_1}; correlogram: {device: [(distance_mm, rho, pairs)]}.
    - rejected_clusters: {device: {"n", "mean_nn_mm", "random_nn_mm", "p", "poses", "centre_mm"}}.
    - warnings: the flagged findings, as sentences."""

    neighbour_correlation: dict
    correlogram: dict
    rejected_clusters: dict
    warnings: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"neighbour_correlation": self.neighbour_correlation, "correlogram": self.correlogram,
                "rejected_clusters": self.rejected_clusters, "warnings": self.warnings}


def _points(ba, obs, device):
    """(view (P,), board xy (P, 2) mm, residual (P, 2) px, inlier (P,)) of one device."""
    m = ba.point_device == device
    views, ids = ba.point_view[m], ba.point_id[m]
    xy = np.empty((len(views), 2))
    for v in np.unique(views):                # each point's board position: the first board point with its id
        at = views == v
        board = obs.views[v]
        order = np.argsort(board.ids, kind="stable")
        xy[at] = board.points_board[order[np.searchsorted(board.ids, ids[at], sorter=order)], :2]
    return views, xy, ba.residuals_px[m], ba.inlier[m]


def _grid_step(obs) -> float:
    X = obs.views[0].points_board[:, :2]
    d = np.linalg.norm(X[:, None] - X[None], axis=2)
    np.fill_diagonal(d, np.inf)
    return float(np.median(d.min(axis=1)))


def _correlogram(views, xy, res, ok, step):
    """[(distance_mm, rho, pairs)] of the inlier residuals (normalised per coordinate) within poses."""
    r = res / np.maximum(np.sqrt(np.mean(res[ok] ** 2, axis=0)), 1e-300)
    edges = np.array(BINS_IN_STEPS) * step
    num, cnt, dist = np.zeros(len(edges) - 1), np.zeros(len(edges) - 1), np.zeros(len(edges) - 1)
    for v in np.unique(views):
        m = (views == v) & ok
        if m.sum() < 2:
            continue
        iu = np.triu_indices(int(m.sum()), 1)
        d = np.linalg.norm(xy[m][:, None] - xy[m][None], axis=2)[iu]
        prod = 0.5 * (np.outer(r[m, 0], r[m, 0]) + np.outer(r[m, 1], r[m, 1]))[iu]
        b = np.digitize(d, edges) - 1
        keep = (b >= 0) & (b < len(num))
        num += np.bincount(b[keep], prod[keep], len(num))
        cnt += np.bincount(b[keep], minlength=len(num))
        dist += np.bincount(b[keep], d[keep], len(num))
    return [(float(dist[k] / cnt[k]), float(num[k] / cnt[k]), int(cnt[k])) for k in range(len(num)) if cnt[k]]


def _nn_mean(xy):
    d = np.linalg.norm(xy[:, None] - xy[None], axis=2)
    np.fill_diagonal(d, np.inf)
    return float(np.mean(d.min(axis=1)))


def _rejected_cluster(views, xy, ok, rng, draws):
    bad = np.flatnonzero(~ok)
    observed = _nn_mean(xy[bad])
    random = np.array([_nn_mean(xy[rng.choice(len(xy), len(bad), replace=False)]) for _ in range(draws)])
    poses, counts = np.unique(views[bad], return_counts=True)
    return {"n": int(len(bad)), "mean_nn_mm": observed, "random_nn_mm": float(np.median(random)),
            "p": float((np.sum(random <= observed) + 1) / (draws + 1)),
            "poses": {int(p): int(c) for p, c in zip(poses, counts)},
            "centre_mm": np.round(xy[bad].mean(axis=0), 2).tolist()}


def diagnose_residuals(cal, obs, *, draws: int = 500, seed: int = 0) -> ResidualDiagnostics:
    """Spatial correlation and rejected-point clustering of ``cal`` (a Calibration of ``obs``);
    the flagged findings are logged as warnings (``calib`` logger) and listed."""
    ba = cal.ba
    step = _grid_step(obs)
    rng = np.random.default_rng(seed)
    rho1, gram, clusters, warnings = {}, {}, {}, []
    for d in ("camera", "projector"):
        if not np.any(ba.point_device == d):
            continue
        views, xy, res, ok = _points(ba, obs, d)
        gram[d] = _correlogram(views, xy, res, ok, step)
        near = [g for g in gram[d] if g[0] < 1.5 * step]
        if near:
            rho, pairs = near[0][1], near[0][2]
            rho1[d] = rho
            if rho > CORRELATION_FLAG and rho * np.sqrt(pairs) > 3:
                warnings.append(f"{d} residuals of neighbouring board points correlate ({rho:.2f} over {pairs} pairs; "
                                "independent errors give ~0): the errors are shared within poses (a board that is not "
                                "flat or not as printed, per-pose drift), so independent-residual sigmas are too small")
        if (~ok).sum() >= 3 and ok.sum() > (~ok).sum():
            c = _rejected_cluster(views, xy, ok, rng, draws)
            clusters[d] = c
            if c["p"] < CLUSTER_P:
                names = {int(p): obs.views[int(p)].name for p in c["poses"]}
                warnings.append(f"the {c['n']} rejected {d} points cluster (mean distance to the nearest other "
                                f"{c['mean_nn_mm']:.1f} mm on the board vs {c['random_nn_mm']:.1f} mm for as many "
                                f"scattered points, p = {c['p']:.3f}): poses "
                                + ", ".join(f"{names[p]} ({n})" for p, n in c["poses"].items())
                                + f", around board ({c['centre_mm'][0]:+.0f}, {c['centre_mm'][1]:+.0f}) mm; a local "
                                "defect (glare, a damaged or lifted board, a decoding error), not noise")
    for w in warnings:
        log.warning(w)
    return ResidualDiagnostics(rho1, gram, clusters, warnings)


def plot_residual_diagnostics(cal, obs, diagnostics: ResidualDiagnostics, out_dir) -> dict:
    """Write ``residuals_per_pose.png`` and ``residuals_on_board.png`` into ``out_dir`` (drawn with
    Pillow: :mod:`calib.uncertainty.diagnostic_figures`); returns {name: path}."""
    from .diagnostic_figures import board_figure, per_pose_figure

    ba, out = cal.ba, Path(out_dir)
    devices = [d for d in ("camera", "projector") if np.any(ba.point_device == d)]
    points = {d: _points(ba, obs, d) for d in devices}
    return {"residuals_per_pose.png": per_pose_figure(cal, obs, devices, points, out / "residuals_per_pose.png"),
            "residuals_on_board.png": board_figure(cal, obs, devices, points, diagnostics,
                                                   out / "residuals_on_board.png")}
