"""Figures of the report, as PNG bytes (matplotlib, Agg backend)."""
from __future__ import annotations

import io

import numpy as np


def _fig_png(fig) -> bytes:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def residual_bars(per_view: dict, title: str) -> bytes:
    """Per-view RMS bars, one group per device. ``per_view``: {label: {device: [rms per view]}}."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.2))
    for ax, kind in zip(axes, ("camera", "projector")):
        labels = [lab for lab in per_view if per_view[lab].get(kind)]
        n = max((len(per_view[lab][kind]) for lab in labels), default=0)
        width = 0.8 / max(len(labels), 1)
        for i, lab in enumerate(labels):
            vals = per_view[lab][kind]
            ax.bar(np.arange(len(vals)) + i * width, vals, width, label=lab)
        ax.set_xticks(np.arange(n) + 0.4 - width / 2, [str(i + 1) for i in range(n)])
        ax.set_xlabel("view")
        ax.set_ylabel("RMS (px)")
        ax.set_title(f"{kind}")
        ax.legend(fontsize=7)
    fig.suptitle(title)
    return _fig_png(fig)


def residual_vectors(views, residuals: dict, device_sizes: dict, title: str) -> bytes:
    """Residual vectors drawn over the image, per device (scaled so they can be seen)."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, kind in zip(axes, ("camera", "projector")):
        if kind not in residuals:
            ax.set_visible(False)
            continue
        q = np.concatenate([v.q[kind] for v in views])
        r = residuals[kind]
        ok = np.all(np.isfinite(q), axis=1)
        q = q[ok][: len(r)]
        norm = np.linalg.norm(r, axis=1)
        scale = 0.05 * max(device_sizes[kind]) / max(np.percentile(norm, 95), 1e-12)
        ax.quiver(q[:, 0], q[:, 1], r[:, 0], r[:, 1], norm, angles="xy", scale_units="xy", scale=1 / scale, cmap="viridis")
        w, h = device_sizes[kind]
        ax.set_xlim(-0.5, w - 0.5)
        ax.set_ylim(h - 0.5, -0.5)
        ax.set_aspect("equal")
        ax.set_title(f"{kind}: residuals x{scale:.0f} (RMS {np.sqrt(np.mean(norm ** 2)):.3f} px)")
    fig.suptitle(title)
    return _fig_png(fig)


def z_scores(rows) -> bytes:
    """Differences twin - real in units of their standard deviation, per parameter."""
    plt = _plt()
    rows = [r for r in rows if np.isfinite(r["z"])]
    fig, ax = plt.subplots(figsize=(10, 3.2))
    labels = [f"{r['device'][:3]}.{r['parameter']}" for r in rows]
    z = [r["z"] for r in rows]
    colors = ["tab:red" if abs(v) > 3 else "tab:orange" if abs(v) > 2 else "tab:green" for v in z]
    ax.bar(range(len(z)), z, color=colors)
    for lim in (-3, 3):
        ax.axhline(lim, color="grey", lw=0.8, ls="--")
    ax.set_xticks(range(len(z)), labels, rotation=60, ha="right", fontsize=8)
    ax.set_ylabel("(twin - real) / sigma")
    ax.set_title("Differences in units of the combined standard deviation (|z| <= 3: noise)")
    return _fig_png(fig)


def sphere_matrix(matrix: dict) -> bytes:
    """Bar chart of sphere-fit RMS (um) per (calibration, phase) cell."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 3))
    labels = list(matrix)
    ax.bar(range(len(labels)), [matrix[k] for k in labels], color="tab:blue")
    ax.set_xticks(range(len(labels)), labels, rotation=20, ha="right", fontsize=8)
    ax.set_ylabel("sphere-fit RMS (um)")
    return _fig_png(fig)
