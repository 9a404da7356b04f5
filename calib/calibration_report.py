"""Outputs of a calibration: calibration.json (DESIGN.md keys + uncertainties), mrcal models,
residual plots (PNG) and the summary table printed by ``calib run``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .calibrate import Calibration
from .errors import FormatError
from .io.calibration_json import write_calibration_json
from .io.mrcal_model import write_cameramodel

PARAMS = ("fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6",
          "s1", "s2", "s3", "s4")


def _reported_std(cal: Calibration) -> dict:
    """{name: 1-sigma}: the uncertainty report's (calib.uncertainty) where there is one, else the
    adjustment's own."""
    std = dict(cal.ba.std)
    if cal.uncertainty is not None:
        std.update(cal.uncertainty.std)
    return std


def uncertainties(cal: Calibration, std: dict | None = None) -> dict:
    """{device: {param: std}} for intrinsics, plus the rig pose (joint mode), 1-sigma: the reported
    uncertainty (``std`` if given, else :func:`_reported_std`)."""
    std = _reported_std(cal) if std is None else std
    out = {}
    for d in ("camera", "projector"):
        e = {p: std[f"{d}.{p}"] for p in PARAMS if f"{d}.{p}" in std}
        if e:
            out[d] = e
    rig = {k.split(".")[1]: v for k, v in std.items() if k.startswith("prj_cam.")}
    if rig:
        out["rt_prj_cam"] = {"rotation_rad": [rig[f"w{j}"] for j in range(3)],
                             "translation_mm": [rig[f"t{j}"] for j in range(3)]}
    warp = {k: v for k, v in std.items() if k.startswith("board_warp.")}
    if warp:
        out["board_warp_mm"] = warp
    return out


def covariance_of_system(cal: Calibration) -> dict:
    """The joint covariance of the device intrinsics and the rig transform (``camera.fx``, ...,
    ``prj_cam.w0..w2`` (rad, tangent: ``R = R0 Exp(w)``), ``prj_cam.t0..t2`` (mm)), without the
    board poses: what a twin needs to draw systems from the calibration's posterior. The reported
    covariance (calib.uncertainty) where there is one, else the adjustment's."""
    u = getattr(cal, "uncertainty", None)
    if u is not None:
        keep = [k for k, n in enumerate(u.cov_names) if not n.startswith("board_warp")]
        return {"names": [u.cov_names[k] for k in keep], "matrix": np.asarray(u.cov)[np.ix_(keep, keep)].tolist(),
                "model": u.reported}
    keep = [k for k, n in enumerate(cal.ba.free_names) if "/" not in n and not n.startswith("board_warp")]
    cov = np.asarray(cal.ba.cov)[np.ix_(keep, keep)]
    return {"names": [cal.ba.free_names[k] for k in keep], "matrix": cov.tolist()}


def calibration_dict_extra(cal: Calibration, obs) -> dict:
    ba = cal.ba
    poses = []
    for i, v in enumerate(obs.views):
        e = {"view": i, "name": v.name}
        for pn, (R, t) in ba.state.poses.items():
            if pn.endswith(f"_board/{i}"):
                e[pn.split("/")[0]] = {"R": np.asarray(R).tolist(), "t": np.asarray(t).tolist()}
        poses.append(e)
    extra = {
        "uncertainties_1sigma": uncertainties(cal),
        "uncertainties_1sigma_independent_residuals": uncertainties(cal, cal.ba.std),
        "covariance": covariance_of_system(cal),
        "residuals": {k: v for k, v in ba.stats.items()},
        "rejected_points": ba.rejected,
        "board_poses": poses,
        "solver": {"mode": ba.mode, "iterations": ba.iterations, "converged": ba.converged,
                   "cost": ba.cost, "residual_variance": ba.sigma2,
                   "device_noise_px": ba.device_sigma_px, "conditioning": ba.conditioning,
                   "poorly_determined": ba.poorly_determined, "residual_kernel": ba.backend,
                   "evaluations": ba.timings.get("evaluations"),
                   "estimated": ba.free_names if len(ba.free_names) < 60 else
                   [n for n in ba.free_names if "/" not in n and not n.startswith("prj_cam")],
                   "seeds": {d: {"method": s.method, "rms_px": s.rms_px,
                                 "K": s.K.tolist()} for d, s in cal.seeds.items()},
                   "log": ba.log},
        "timings_s": cal.timings,
        "source": str(obs.source),
    }
    if ba.state.warp.any():
        extra["board_warp_mm"] = ba.state.warp.tolist()
    if cal.uncertainty is not None:
        extra["uncertainty"] = cal.uncertainty.to_dict()
    if cal.baseline_scatter_mm is not None:
        extra["seed_baseline_scatter_mm"] = cal.baseline_scatter_mm
    return extra


def plot_residuals(cal: Calibration, obs, path) -> Path:
    """Residual scatter per device and per-view RMS bars (PNG)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure   # no pyplot: no global state, a faster import

    ba = cal.ba
    devices = [d for d in ("camera", "projector") if d in ba.stats]
    fig = Figure(figsize=(5.5 * len(devices), 9))
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, len(devices), squeeze=False)
    for k, d in enumerate(devices):
        m = ba.point_device == d
        ax = axes[0, k]
        sc = ax.scatter(ba.residuals_px[m & ba.inlier, 0], ba.residuals_px[m & ba.inlier, 1], s=6,
                        c=ba.point_view[m & ba.inlier], cmap="viridis")
        if (m & ~ba.inlier).any():
            ax.scatter(ba.residuals_px[m & ~ba.inlier, 0], ba.residuals_px[m & ~ba.inlier, 1], s=18,
                       marker="x", c="red", label="rejected")
            ax.legend()
        ax.set_title(f"{d}: residuals (px), RMS {ba.stats[d]['rms_px']:.4f}")
        ax.set_xlabel("du (px)")
        ax.set_ylabel("dv (px)")
        ax.axis("equal")
        fig.colorbar(sc, ax=ax, label="view")
        ax = axes[1, k]
        rms = [v[d]["rms_px"] or 0.0 for v in ba.stats["views"]]
        ax.bar(np.arange(len(rms)), rms)
        ax.set_xlabel("view")
        ax.set_ylabel("RMS residual (px)")
        ax.set_title(f"{d}: per-view RMS")
    # fixed margins: tight_layout would draw the figure once more to measure it (a third of the time)
    fig.subplots_adjust(left=0.08, right=0.97, bottom=0.06, top=0.96, wspace=0.3, hspace=0.25)
    path = Path(path)
    fig.savefig(path, dpi=100)
    return path


def summary_table(cal: Calibration) -> str:
    """Plain-text table: parameter, value, 1-sigma, per device; residuals; timings."""
    lines = [f"{'parameter':<22}{'value':>16}{'std (1 sigma)':>16}"]
    unc = uncertainties(cal)
    flagged = {f["name"]: f for f in getattr(cal.ba, "poorly_determined", [])}
    for d in ("camera", "projector"):
        dev = getattr(cal.system, d)
        if d not in unc:
            continue
        vals = {"fx": dev.fx, "fy": dev.fy, "cx": dev.cx, "cy": dev.cy, "skew": dev.skew}
        vals.update(dict(zip(PARAMS[5:], dev.distortion)))
        for p, v in vals.items():
            s = unc[d].get(p)
            flag = "  poorly determined *" if f"{d}.{p}" in flagged else ""
            lines.append(f"{d + '.' + p:<22}{v:>16.6g}{('%.3g' % s) if s is not None else 'fixed':>16}{flag}")
    if "rt_prj_cam" in unc:
        Rpc_t = cal.ba.state.poses["prj_cam"][1]
        for j, a in enumerate("xyz"):
            lines.append(f"{'t_prj_cam.' + a + ' (mm)':<22}{Rpc_t[j]:>16.6g}"
                         f"{unc['rt_prj_cam']['translation_mm'][j]:>16.3g}")
    if "board_warp_mm" in unc:
        for j, a in enumerate("xy"):
            lines.append(f"{'board_warp.c' + a + ' (mm)':<22}{cal.ba.state.warp[j]:>16.4g}"
                         f"{unc['board_warp_mm'][f'board_warp.c{a}']:>16.3g}")
    if cal.uncertainty is not None:
        lines.append(f"(std: {cal.uncertainty.reported}; the adjustment's independent-residual sigmas and the "
                     "comparison: the uncertainty table below)")
    if flagged:
        lines.append("* the observations hardly determine these (consider fixing them, e.g. --fix camera.k3, "
                     "or more / wider views):")
        lines += [f"    {n}: {'; '.join(f['reasons'])}" for n, f in flagged.items()]
    lines.append("")
    lines.append(f"{'residuals':<12}{'points':>8}{'RMS px':>10}{'max px':>10}{'rejected':>10}")
    for d in ("camera", "projector"):
        if d in cal.ba.stats:
            s = cal.ba.stats[d]
            nrej = sum(1 for r in cal.ba.rejected if r["device"] == d)
            lines.append(f"{d:<12}{s['n']:>8}{s['rms_px']:>10.4f}{s['max_px']:>10.4f}{nrej:>10}")
    g = cal.ba.stats.get("projector", {}).get("rms_given_camera_px")
    if g is not None:
        lines.append(f"projector pixels given the camera's (camera error transfer, "
                     f"{cal.ba.stats['projector']['n_transferred']} points): RMS {g:.4f} px")
    t = cal.timings
    lines.append("")
    lines.append(f"time: init {t['init_s']:.3f} s, build {t['build_s']:.3f} s, solve {t['solve_s']:.3f} s, "
                 f"total {t['total_s']:.3f} s; {cal.ba.iterations} iterations, converged={cal.ba.converged}")
    return "\n".join(lines)


def write_outputs(cal: Calibration, obs, out_dir, *, skew_tol_px: float = 0.01, extra: dict | None = None) -> dict:
    """Write calibration.json, camera/projector.cameramodel, residuals.png; return {name: path or note}.
    ``extra``: more top-level keys for calibration.json (e.g. ``captures``, the image pipeline's summary)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = {}
    keys = calibration_dict_extra(cal, obs)
    keys.update(extra or {})
    written["calibration.json"] = write_calibration_json(cal.system, out / "calibration.json", **keys)
    only = cal.system.meta.get("only_device")
    for d in ("camera", "projector"):
        if only and d != only:
            continue
        try:
            write_cameramodel(getattr(cal.system, d), out / f"{d}.cameramodel", skew_tol_px=skew_tol_px)
            written[f"{d}.cameramodel"] = out / f"{d}.cameramodel"
        except FormatError as exc:
            written[f"{d}.cameramodel"] = f"not written: {exc}"
    written["residuals.png"] = plot_residuals(cal, obs, out / "residuals.png")
    return written
