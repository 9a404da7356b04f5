"""The twin-equivalence report: real vs twin calibration, twin parameters, residuals, cross
reprojection, run facts. ``build_twin_report`` returns the sections; ``write_twin_report`` writes
``report.html`` (self-contained) and ``report.md``.
"""
from __future__ import annotations

import json
import platform
import time
from pathlib import Path

import numpy as np

from calib.board_pose import cross_reprojection
from unwrap.safe_output import write_text

from .compare import parameter_rows, rig_rows
from .html import to_html, to_markdown
from .inputs import CalibrationRecord, check_comparable, load_calibration_record


def _versions() -> dict:
    import importlib.metadata as md

    out = {"python": platform.python_version()}
    for pkg in ("sltwin", "numpy", "scipy", "opencv-contrib-python-headless", "casadi", "torch", "matplotlib"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            pass
    return out


def _calibration_section(real, twin, rows):
    table = []
    for r in rows:
        flag = ""
        if np.isfinite(r["z"]) and abs(r["z"]) > 3:
            flag = "expected: the twin has none" if r.get("expected") else "! beyond 3 sigma"
        table.append([r["device"], r["parameter"], r["real"], r["twin"], r["difference"], r["sigma"], r["z"], flag])
    blocks = [("p", f"Left: {real.label}; right: {twin.label}. sigma combines both calibrations' 1-sigma "
                    "standard deviations (Bouguet inputs: the toolbox's 3-sigma errors / 3); z = difference / sigma. "
                    "|z| <= 3 is what calibration noise alone explains. Extrinsics depend on each calibration's own "
                    "world frame (its board pose 1), so they are compared through the rig below. Skew and lens "
                    "distortion marked 'expected' are terms the twin does not have: Blender renders ideal pinholes "
                    "(they are listed under not_representable in twin.json, with their effect in pixels), so a twin "
                    "calibration finds them at zero, whatever the real lens has; they are not a twin mismatch."),
              ("table", ["device", "parameter", real.label, twin.label, "twin - real", "sigma", "z", ""], table)]
    if any(np.isfinite(r["z"]) for r in rows):
        from .figures import z_scores
        blocks.append(("figure", z_scores(rows), "differences in units of sigma"))
    rig = rig_rows(real, twin)
    blocks.append(("table", ["rig (projector from camera)", "t_prj_cam (mm)", "baseline (mm)"],
                   [[r["label"], " ".join(f"{v:.3f}" for v in r["t_prj_cam"]), r["baseline_mm"]] for r in rig[:2]]))
    d = rig[2]
    blocks.append(("p", f"Rig difference twin - real: rotation {d['rotation_deg']:.4f} deg, translation "
                        f"{' '.join(f'{v:+.3f}' for v in d['t_diff_mm'])} mm, baseline {d['baseline_diff_mm']:+.3f} mm."))
    return blocks


def _paper_section(real, twin):
    from twin_mapping.paper import compare_with_table_s3
    from twin_mapping.paper_tables import TABLE_S4
    from twin_mapping.table import is_papers_system
    from twin_mapping.twin import to_twin

    if not is_papers_system(real.system):
        return None
    twin_params = to_twin(real.system)
    rows = compare_with_table_s3(twin_params)
    blocks = [("p", "The real calibration is the paper's system: its twin parameters (table S3 layout) beside the "
                    "values printed in the paper. A value that does not reproduce is flagged, never replaced."),
              ("table", ["device", "quantity", "axis", "ours", "paper", "ours - paper", "status"],
               [[r["device"], r["quantity"], r["axis"], r["ours"], r["printed_text"], r["difference"],
                 r["status"] if r["status"] == "reproduces" else f"! {r['status']}: {r['note']}"] for r in rows])]
    s4 = []
    for kind in ("camera", "projector"):
        dev = getattr(twin.system, kind)
        for p in ("fx", "fy", "cx", "cy", "skew"):
            ours = getattr(dev, p)
            s4.append([kind, p, ours, TABLE_S4[kind][p], ours - TABLE_S4[kind][p]])
    blocks += [("p", f"Table S4 (the paper's calibration inside its twin) beside {twin.label}:"),
               ("table", ["device", "parameter", twin.label, "paper S4", "difference"], s4)]
    return blocks


def _residual_section(real, twin):
    from .figures import residual_bars, residual_vectors

    blocks = []
    per_view = {rec.label: rec.residual_rms_px for rec in (real, twin) if rec.residual_rms_px}
    if per_view:
        blocks.append(("figure", residual_bars(per_view, "per-view reprojection RMS, each calibration on its own data"),
                       "per-view, per-device residual RMS"))
        rows = []
        for lab, d in per_view.items():
            for kind, v in d.items():
                rows.append([lab, kind, float(np.sqrt(np.mean(np.square(v)))), float(np.max(v)), len(v)])
        blocks.append(("table", ["calibration", "device", "RMS over views (px)", "worst view (px)", "views"], rows))
    return blocks


def _cross_section(real, twin, timings):
    from .figures import residual_vectors

    if not (real.views and twin.views):
        return [("p", "Cross reprojection needs board observations on both sides (a Bouguet pair, or "
                      "observations.json beside calibration.json); not available for these inputs.")]
    t0 = time.perf_counter()
    rows, figs = [], []
    for obs in (real, twin):
        for rig in (real, twin):
            r = cross_reprojection(obs, rig.system)
            rows.append([f"{obs.label} observations", f"{rig.label} rig", r["rms_px"].get("camera", float("nan")),
                         r["rms_px"].get("projector", float("nan")), len(obs.views)])
            if obs is not rig:
                sizes = {k: getattr(rig.system, k).size for k in ("camera", "projector")}
                figs.append(("figure", residual_vectors(obs.views, r["residuals"], sizes,
                                                        f"{obs.label} board points through the {rig.label} rig"),
                             f"{obs.label} observations through the {rig.label} calibration"))
    timings["cross_reprojection_s"] = time.perf_counter() - t0
    return [("p", "Each view's board pose is fitted to the camera AND projector pixels through one calibration's "
                  "whole rig (intrinsics, distortion, skew, camera-projector pose); the RMS says how well that rig "
                  "explains the observations. The diagonal is each calibration on its own data."),
            ("table", ["observations", "through", "camera RMS (px)", "projector RMS (px)", "views"], rows)] + figs


def build_twin_report(real: CalibrationRecord, twin: CalibrationRecord, *, extra_sections=()) -> tuple[list, dict]:
    """Sections of the report and a JSON-ready summary."""
    check_comparable(real, twin)
    timings = {}
    t0 = time.perf_counter()
    rows = parameter_rows(real, twin)
    sections = [("Real vs twin calibration", _calibration_section(real, twin, rows))]
    paper = _paper_section(real, twin)
    if paper:
        sections.append(("Twin parameters and the paper's tables", paper))
    res = _residual_section(real, twin)
    if res:
        sections.append(("Residuals", res))
    sections.append(("Cross reprojection", _cross_section(real, twin, timings)))
    sections += list(extra_sections)
    timings["report_s"] = time.perf_counter() - t0
    files = {**real.files, **twin.files}
    sections.append(("Run facts", [
        ("table", ["item", "value"], [[k, v] for k, v in _versions().items()]),
        ("table", ["input", "sha256"], [[k, v] for k, v in files.items()]),
        ("table", ["step", "seconds"], [[k, v] for k, v in timings.items()]),
        ("p", f"generated {time.strftime('%Y-%m-%d %H:%M:%S %Z')} on {platform.node()}"),
    ]))
    summary = {"parameters": [{k: (None if isinstance(v, float) and v != v else v) for k, v in r.items()} for r in rows],
               "beyond_3_sigma": [f"{r['device']}.{r['parameter']}" for r in rows
                                  if np.isfinite(r["z"]) and abs(r["z"]) > 3 and not r.get("expected")],
               "expected_differences": [f"{r['device']}.{r['parameter']}" for r in rows
                                        if np.isfinite(r["z"]) and abs(r["z"]) > 3 and r.get("expected")],
               "inputs": files, "timings_s": timings}
    return sections, summary


def write_twin_report(real_paths, twin_paths, out_dir, *, title="Twin-equivalence report", extra_sections=(),
                      phases: dict | None = None, frequency: float = 96.0, twin_ball=None) -> dict:
    """Read both calibrations, build the report, write report.html, report.md and summary.json.

    ``phases``: optional ``{"real": path, "twin": path}`` absolute phase maps of the same sphere
    (vertical fringes, ``frequency`` periods): adds the paper's Fig. 3 cross-reconstruction matrix.
    ``twin_ball``: the twin ball rendered at the real ball's fitted pose, ``(phase, info)`` of
    :func:`experiments.twin_ball.twin_ball_for_report` (phase label "twin (synth)"): its phase joins
    the matrix, its facts the summary.
    """
    real = load_calibration_record(real_paths, "real")
    twin = load_calibration_record(twin_paths, "twin")
    extra = list(extra_sections)
    sphere_rows = ball_info = None
    phases = dict(phases or {})
    out = Path(out_dir)
    if phases:
        from unwrap.phase_io import read_phase

        from .sphere_matrix import sphere_section
        check_comparable(real, twin)
        maps = {k: read_phase(v) for k, v in phases.items()}
        extra_rows, ball_blocks = [], []
        if twin_ball is not None:
            from .twin_ball_section import TWIN_RENDER_LABEL, floor_rows, twin_ball_blocks

            phase, ball_info = twin_ball
            maps[TWIN_RENDER_LABEL] = phase
            extra_rows = floor_rows(ball_info)
            ball_blocks = twin_ball_blocks(ball_info, maps["real"], phase)
        sphere_rows, blocks = sphere_section({"real": real.system, "twin": twin.system}, maps, frequency, extra_rows)
        extra.insert(0, ("Cross reconstruction of the ball (Fig. 3)", blocks + ball_blocks))
    sections, summary = build_twin_report(real, twin, extra_sections=extra)
    if sphere_rows is not None:
        summary["sphere_matrix"] = sphere_rows
    if ball_info is not None:
        summary["twin_ball"] = ball_info
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / "report.html", to_html(title, sections))
    write_text(out / "report.md", to_markdown(title, sections))
    write_text(out / "summary.json", json.dumps(summary, indent=2, default=float) + "\n")
    summary["paths"] = {k: str(out / f"report.{k}") for k in ("html", "md")}
    return summary
