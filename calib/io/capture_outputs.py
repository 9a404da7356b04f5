"""Files ``calib run CAPTURES`` writes besides the calibration: the observations it extracted
(``observations.json``, re-runnable with ``calib run --observations``) and a figure of the
detections (``detections.png``: every pose's board image with its features, green where the
projector pixel was fitted, red where it was not)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from unwrap.safe_output import save_figure

from ..observations import write_observations_json


def plot_detections(captured, path) -> Path:
    """One panel per pose: the board image with the detected features (camera pixels)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    poses = captured.poses
    n = len(poses)
    cols = min(3, n)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, p in zip(axes.ravel(), poses):
        if p.image is not None:
            img = p.image
            lo, hi = np.nanpercentile(img, [1, 99.5])
            ax.imshow(img, cmap="gray", vmin=lo, vmax=hi if hi > lo else lo + 1)
        fitted = np.isfinite(p.q_prj).all(axis=1)
        ax.scatter(p.q_cam[fitted, 0], p.q_cam[fitted, 1], s=6, c="lime", linewidths=0)
        ax.scatter(p.q_cam[~fitted, 0], p.q_cam[~fitted, 1], s=14, c="red", marker="x")
        ax.set_title(f"{p.name}: {len(p.ids)} features on {p.board_image}, "
                     f"{int(fitted.sum())} with projector px", fontsize=8)
    fig.tight_layout()
    try:
        return save_figure(fig, path, dpi=90)      # atomic: a failed write leaves the previous file
    finally:
        plt.close(fig)


def write_capture_outputs(captured, out_dir) -> dict:
    """Write observations.json and detections.png into ``out_dir``; returns {name: path}."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return {"observations.json": write_observations_json(captured.observations, out / "observations.json"),
            "detections.png": plot_detections(captured, out / "detections.png")}
