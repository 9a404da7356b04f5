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
    colors = ["tab:gray" if r.get("expected") else "tab:red" if abs(v) > 3 else "tab:orange" if abs(v) > 2
              else "tab:green" for r, v in zip(rows, z)]
    ax.bar(range(len(z)), z, color=colors)
    if any(r.get("expected") for r in rows):
        ax.text(0.01, 0.97, "grey: skew / distortion the twin does not have (Blender renders ideal pinholes)",
                transform=ax.transAxes, va="top", fontsize=8, color="tab:gray")
    for lim in (-3, 3):
        ax.axhline(lim, color="grey", lw=0.8, ls="--")
    ax.set_xticks(range(len(z)), labels, rotation=60, ha="right", fontsize=8)
    ax.set_ylabel("(twin - real) / sigma")
    ax.set_title("Differences in units of the combined standard deviation (|z| <= 3: noise)")
    return _fig_png(fig)


def sphere_matrix(matrix: dict) -> bytes:
    """Horizontal bar chart of sphere-fit RMS (um) per (phase, calibration, method) cell: one row
    per cell, its label beside the bar and its value at the bar's end (long labels never overlap)."""
    plt = _plt()
    labels = list(matrix)
    values = [matrix[k] for k in labels]
    fig, ax = plt.subplots(figsize=(8, 0.9 + 0.32 * len(labels)))
    y = np.arange(len(labels))[::-1]
    ax.barh(y, values, color="tab:blue")
    ax.set_yticks(y, labels, fontsize=8)
    for yi, v in zip(y, values):
        ax.text(v, yi, f" {v:.1f}", va="center", fontsize=8)
    ax.set_xlim(0, 1.15 * max(values) if values else 1)
    ax.set_xlabel("sphere-fit RMS (um)")
    return _fig_png(fig)
