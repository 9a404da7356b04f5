"""Outputs of a calibration: calibration.json (DESIGN.md keys + uncertainties), mrcal models,
residual plots (PNG) and the summary table printed by ``calib run``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..calibrate import Calibration
from ..errors import FormatError
from .calibration_json import write_calibration_json
from .mrcal_model import write_cameramodel

PARAMS = ("fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6",
          "s1", "s2", "s3", "s4")


def _reported_std(cal: Calibration) -> dict:
    """{name: 1-sigma}: the uncertainty report's (calib.uncertainty.assess) where there is one, else the
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
    covariance (calib.uncertainty.assess) where there is one, else the adjustment's."""
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
        "outlier_rule": outlier_summary(cal, obs),
        "view_noise": cal.view_noise,
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


def outlier_summary(cal: Calibration, obs) -> dict:
    """The rejection rule beside what a Gaussian expects, per device.

    The rule (:mod:`calib.adjustment.solver`): a point whose normalised residual norm |e| exceeds
    ``threshold`` robust sigmas (sigma per coordinate from the median of |e|^2 over the kept
    points, iterated) is rejected. At that sigma a Gaussian gives ``|e| / sigma`` a Rayleigh
    distribution, so ``n exp(-threshold^2 / 2)`` of n points are expected beyond the threshold.
    Returns {device: {"points", "rejected", "threshold_sigma", "robust_sigma_px", "expected",
    "quantiles" (50/90/99/100 % of |e| / sigma), "rejected_by_view"}} ({} without rejection)."""
    from ..calibrate import sigma_of_points

    ba, t = cal.ba, cal.outlier_threshold
    if t is None:
        return {}
    e_all = np.linalg.norm(ba.residuals_px, axis=1) / sigma_of_points(obs, ba)
    out = {}
    for d in ("camera", "projector"):
        m = ba.point_device == d
        if not m.any():
            continue
        e, kept = e_all[m], ba.inlier[m]
        sigma = float(np.sqrt(np.median(e[kept] ** 2) / (2 * np.log(2))))
        views = ba.point_view[m][~kept]
        out[d] = {"points": int(m.sum()), "rejected": int((~kept).sum()), "threshold_sigma": float(t),
                  "robust_sigma_px": sigma, "expected": float(m.sum() * np.exp(-t * t / 2)),
                  "quantiles": np.quantile(e / sigma, [0.5, 0.9, 0.99, 1.0]).round(3).tolist(),
                  "rejected_by_view": {int(v) + 1: int((views == v).sum()) for v in np.unique(views)}}
    return out


def plot_residuals(cal: Calibration, obs, path) -> Path:
    """Residual scatter per device (coloured by view), per-view RMS and the residual distribution
    beside a Gaussian's, with the rejection threshold (PNG, written atomically): the figure
    ``calib run`` draws by default, drawn with Pillow, not matplotlib
    (:func:`calib.io.summary_figure.summary_figure`, ~0.1 s against ~1 s; docs/speed.md)."""
    from .summary_figure import summary_figure

    return summary_figure(cal, obs, path)


def summary_table(cal: Calibration, obs=None, skipped=None) -> str:
    """Plain-text table: parameter, value, 1-sigma, per device; residuals (with the outlier rule
    beside a Gaussian's expectation when ``obs`` is given); the views used (and ``skipped``
    {name: reason}); timings."""
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
    lines.append(f"{'residuals':<12}{'points':>8}{'RMS px':>10}{'max px':>10}{'rejected':>10}{'Gaussian expects':>18}")
    rule = outlier_summary(cal, obs) if obs is not None else {}
    for d in ("camera", "projector"):
        if d in cal.ba.stats:
            s = cal.ba.stats[d]
            nrej = sum(1 for r in cal.ba.rejected if r["device"] == d)
            expect = f"{rule[d]['expected']:.2g}" if d in rule else "-"
            lines.append(f"{d:<12}{s['n']:>8}{s['rms_px']:>10.4f}{s['max_px']:>10.4f}{nrej:>10}{expect:>18}")
    if rule:
        t = next(iter(rule.values()))["threshold_sigma"]
        lines.append(f"outlier rule: |residual| > {t:g} robust sigma (iterated); the last column is what a Gaussian "
                     "at that sigma puts beyond it" + "".join(
                         f"; {d} rejections by view {r['rejected_by_view']}" for d, r in rule.items() if r["rejected"]))
    if cal.view_noise:
        lines.append("views weighted by their own noise: " + "; ".join(
            f"{d} " + ", ".join(f"view {v + 1} x{f:.2f}" for v, f in fv.items()) for d, fv in cal.view_noise.items()))
    g = cal.ba.stats.get("projector", {}).get("rms_given_camera_px")
    if g is not None:
        lines.append(f"projector pixels given the camera's (camera error transfer, "
                     f"{cal.ba.stats['projector']['n_transferred']} points): RMS {g:.4f} px")
    if obs is not None:
        used = len(obs.views)
        lines.append(f"views used: {used}" + (f" of {used + len(skipped)}; skipped: " + "; ".join(
            f"{k}: {v}" for k, v in skipped.items()) if skipped else ""))
    t = cal.timings
    lines.append("")
    lines.append(f"time: init {t['init_s']:.3f} s, build {t['build_s']:.3f} s, solve {t['solve_s']:.3f} s, "
                 f"total {t['total_s']:.3f} s; {cal.ba.iterations} iterations, converged={cal.ba.converged}")
    return "\n".join(lines)


def write_outputs(cal: Calibration, obs, out_dir, *, skew_tol_px: float = 0.01, extra: dict | None = None,
                  figures: bool = True) -> dict:
    """Write calibration.json, camera/projector.cameramodel, residuals.png (unless ``figures`` is
    False); return {name: path or note}.
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
    if figures:
        written["residuals.png"] = plot_residuals(cal, obs, out / "residuals.png")
    return written
