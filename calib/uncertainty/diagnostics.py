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

from unwrap.safe_output import save_figure

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


def _figure(nrows, ncols, w, h):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w * ncols, h * nrows))
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrows, ncols, squeeze=False)


def plot_residual_diagnostics(cal, obs, diagnostics: ResidualDiagnostics, out_dir) -> dict:
    """Write ``residuals_per_pose.png`` and ``residuals_on_board.png`` into ``out_dir``; returns
    {name: path}."""
    ba, out = cal.ba, Path(out_dir)
    devices = [d for d in ("camera", "projector") if np.any(ba.point_device == d)]
    n = len(obs.views)
    fig, axes = _figure(len(devices), n, 3.2, 2.9)
    for row, d in enumerate(devices):
        views, _, res, ok = _points(ba, obs, d)
        q_all = np.concatenate([obs.views[v].q[d][obs.views[v].seen(d)] for v in range(n) if d in obs.views[v].q])
        scale = 0.05 * max(np.ptp(q_all[:, 0]), 1.0) / max(np.sqrt(np.mean(res[ok] ** 2)), 1e-12)
        for v in range(n):
            ax = axes[row, v]
            m = views == v
            ids = ba.point_id[ba.point_device == d][m]
            q = np.array([obs.views[v].q[d][np.flatnonzero(obs.views[v].ids == i)[0]] for i in ids]).reshape(-1, 2)
            good = ok[m]
            ax.quiver(q[good, 0], q[good, 1], res[m][good, 0], -res[m][good, 1], angles="xy", scale_units="xy",
                      scale=1 / scale, width=0.004, color="tab:blue")
            ax.scatter(q[~good, 0], q[~good, 1], marker="x", c="red", s=16)
            ax.set_xlim(0, obs.sizes[d][0])
            ax.set_ylim(obs.sizes[d][1], 0)
            ax.set_aspect("equal")
            rms = np.sqrt(np.mean(res[m][good] ** 2)) if good.any() else np.nan
            ax.set_title(f"{d} {obs.views[v].name}\nRMS {rms:.3f} px, {int((~good).sum())} rejected", fontsize=7)
            # the frame is the device's image (limits above); tick labels on every small panel cost
            # half of `calib run`'s drawing time and are unreadable at this size
            ax.set_xticks([])
            ax.set_yticks([])
    fig.suptitle(f"residual vectors (x {scale:.0f}) at the observed pixels (each panel: the whole image); "
                 "red x: rejected", fontsize=9)
    fig.subplots_adjust(left=0.03, right=0.99, bottom=0.04, top=0.86, wspace=0.25, hspace=0.5)
    paths = {"residuals_per_pose.png": out / "residuals_per_pose.png"}
    save_figure(fig, paths["residuals_per_pose.png"], dpi=90)
    paths["residuals_on_board.png"] = _plot_board(ba, obs, devices, diagnostics, out / "residuals_on_board.png")
    return paths


def _plot_board(ba, obs, devices, diagnostics, path):
    fig, axes = _figure(1, len(devices) + 1, 4.6, 4.2)
    colours = [f"C{k % 10}" for k in range(len(obs.views))]
    for k, d in enumerate(devices):
        ax = axes[0, k]
        views, xy, res, ok = _points(ba, obs, d)
        scale = 0.04 * max(np.ptp(xy[:, 0]), 1.0) / max(np.sqrt(np.mean(res[ok] ** 2)), 1e-12)
        for v in np.unique(views):
            m = (views == v) & ok
            ax.quiver(xy[m, 0], xy[m, 1], res[m, 0], -res[m, 1], angles="xy", scale_units="xy", scale=1 / scale,
                      width=0.003, color=colours[int(v)], label=obs.views[int(v)].name)
        ax.scatter(xy[~ok, 0], xy[~ok, 1], marker="x", c="red", s=22, label="rejected")
        ax.set_aspect("equal")
        ax.set_xlabel("board x (mm)")
        ax.set_ylabel("board y (mm)")
        rho = diagnostics.neighbour_correlation.get(d)
        ax.set_title(f"{d}: residuals on the board (x {scale:.0f})\nneighbour correlation "
                     f"{'n/a' if rho is None else f'{rho:.2f}'}", fontsize=8)
        ax.legend(fontsize=5, loc="upper right")
    ax = axes[0, -1]
    for d in devices:
        g = np.array(diagnostics.correlogram.get(d, [])).reshape(-1, 3)
        if len(g):
            ax.plot(g[:, 0], g[:, 1], "o-", label=d)
    ax.axhline(0, color="grey", lw=0.8)
    ax.set_xscale("log")
    # plain tick labels (decades, and 2, 3, 5 x 10^k between them): the default ones (10^k, 3x10^k)
    # go through mathtext, whose parser costs ~0.2 s to build, a fifth of this figure
    from matplotlib.ticker import FuncFormatter

    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(FuncFormatter(
        lambda v, _: f"{v:g}" if v > 0 and round(v / 10 ** np.floor(np.log10(v))) in (2, 3, 5) else ""))
    ax.set_xlabel("distance on the board (mm)")
    ax.set_ylabel("residual correlation within a pose")
    ax.set_title("correlogram (independent errors: 0)", fontsize=8)
    ax.legend(fontsize=7)
    fig.subplots_adjust(left=0.06, right=0.98, bottom=0.12, top=0.88, wspace=0.3)
    return save_figure(fig, path, dpi=90)
