"""Report blocks for the twin ball render (``reports.twin_ball``): what was rendered, how the
noise and footprint were matched, the floor, and a figure of both phase maps."""
from __future__ import annotations

import numpy as np

from .figures import _fig_png, _plt

TWIN_RENDER_LABEL = "twin (synth)"
TRUE_TWIN_LABEL = "true twin (render system)"


def floor_rows(info: dict) -> list[dict]:
    """Matrix rows of the rendered phase reconstructed with the system that rendered it."""
    rows = []
    for key, what in (("render_and_decode", "float images (render + decode)"), ("noise_free_8bit", "8-bit, no noise"),
                      ("rendered", "as returned")):
        f = info["floor"][key]
        for method, k in (("linear", "linear_um"), ("distortion-aware", "distortion_aware_um")):
            rows.append({"phase": f"{TWIN_RENDER_LABEL}: {what}", "calibration": TRUE_TWIN_LABEL, "method": method,
                         "rms_um": f[k], "radius_mm": f["radius_mm"], "points": f["points"], "centre_mm": None,
                         "paper_um": None, "ratio": None})
    return rows


def phase_figure(real_phase, twin_phase) -> bytes:
    """Real and rendered twin phase, their footprints, and real - twin where both are valid (rad)."""
    plt = _plt()
    both = np.isfinite(real_phase) | np.isfinite(twin_phase)
    ys, xs = np.nonzero(both)
    pad = 8
    sl = (slice(max(ys.min() - pad, 0), ys.max() + pad + 1), slice(max(xs.min() - pad, 0), xs.max() + pad + 1))
    r, t = real_phase[sl], twin_phase[sl]
    fig, axes = plt.subplots(1, 4, figsize=(13, 3.4))
    lo, hi = np.nanmin([np.nanmin(r), np.nanmin(t)]), np.nanmax([np.nanmax(r), np.nanmax(t)])
    for ax, img, title in ((axes[0], r, "real phase (rad)"), (axes[1], t, "twin phase, synth (rad)")):
        im = ax.imshow(img, vmin=lo, vmax=hi, cmap="viridis")
        ax.set_title(title, fontsize=9)
        fig.colorbar(im, ax=ax, fraction=0.046)
    fp = np.zeros(r.shape + (3,))
    fp[np.isfinite(r) & np.isfinite(t)] = (0.6, 0.6, 0.6)
    fp[np.isfinite(r) & ~np.isfinite(t)] = (0.85, 0.2, 0.2)
    fp[~np.isfinite(r) & np.isfinite(t)] = (0.2, 0.3, 0.9)
    axes[2].imshow(fp)
    axes[2].set_title("footprint: both / real only (red) / twin only (blue)", fontsize=8)
    d = r - t
    m = np.nanpercentile(np.abs(d), 99) if np.isfinite(d).any() else 1.0
    im = axes[3].imshow(d, cmap="coolwarm", vmin=-m, vmax=m)
    axes[3].set_title("real - twin (rad)", fontsize=9)
    fig.colorbar(im, ax=axes[3], fraction=0.046)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    return _fig_png(fig)


def twin_ball_blocks(info: dict, real_phase, twin_phase) -> list:
    """Paragraphs, a facts table and the figure of one twin ball render."""
    p, n, f, fl = info["pose"], info["noise"], info["footprint"], info["floor"]
    c = p["centre_cam_mm"]
    facts = [
        ["sphere centre, camera frame (mm)", " ".join(f"{v:.3f}" for v in c)],
        ["sphere centre, world frame = board pose 1 (mm)", " ".join(f"{v:.3f}" for v in p["centre_world_mm"])],
        ["fitted radius (mm)", p["radius_mm"]],
        ["fit RMS, real phase + real calibration, distortion-aware (um)", p["rms_um"]],
        ["rendered radius (mm)", p["rendered_radius_mm"]],
        ["fringes", f"v, f = {', '.join(f'{x:g}' for x in info['patterns']['frequencies'])}, "
                    f"{info['patterns']['steps']} steps, {info['patterns']['bits']}-bit camera, MF unwrapping"],
        ["phase noise, real (rad)", n["real_rad"]],
        ["phase noise, twin as rendered (rad)", n["twin_rad"]],
        ["phase noise, 8-bit quantisation alone (rad)", n["quantisation_only_rad"]],
        ["twin sensor", n["model"]],
        ["valid pixels: real / twin / lit", f"{f['real_pixels']} / {f['pixels']} / {f['lit_pixels']}"],
        ["footprint IoU (twin vs real)", f["iou"]],
        ["footprint IoU, all decoded pixels / all lit pixels", f"{f['iou_decoded']:.4f} / {f['iou_lit']:.4f}"],
        ["fringe-order errors in the footprint", info["decoding"]["order_errors_in_footprint"]],
        ["real - twin truth phase: mean / std (projector px)",
         f"{info['real_minus_twin_truth']['mean_prj_px']:+.4f} / {info['real_minus_twin_truth']['std_prj_px']:.4f}"],
        ["floor: float render + decode, true twin system, distortion-aware (um)",
         fl["render_and_decode"]["distortion_aware_um"]],
        ["floor: 8-bit noise-free, true twin system, distortion-aware (um)", fl["noise_free_8bit"]["distortion_aware_um"]],
        ["floor: as rendered, true twin system, distortion-aware (um)", fl["rendered"]["distortion_aware_um"]],
        ["render time (s)", info["timings_s"]["total"]],
    ]
    return [("p", "Twin phase rendered by synth for the pose of the real ball: the real phase is reconstructed with "
                  "the real calibration (distortion-aware), a sphere is fitted, and a ball of that radius is placed at "
                  "the same place relative to the twin's camera; its fringe images are decoded by unwrap. The noise "
                  "of the real phase is measured by robust second differences and the twin camera's shot noise is "
                  "set to give the same phase noise; the twin keeps as many valid pixels as the real map, those of "
                  "highest modulation. Reconstructed with the system that rendered it, the rendered phase shows the "
                  "floor of the twin phase itself."),
            ("table", ["twin ball", "value"], facts),
            ("figure", phase_figure(real_phase, twin_phase), "real and rendered twin phase of the ball")]
