"""Plain-text tables of a twin, with the paper's printed table S3 beside it when relevant."""
from __future__ import annotations

import numpy as np

from .paper import compare_with_table_s3


def is_papers_system(system, rtol: float = 1e-6) -> bool:
    """True when ``system`` is the paper's real system (our built-in default), to ``rtol``."""
    from calib.system import default_system

    ref = default_system()
    for a, b in ((system.camera, ref.camera), (system.projector, ref.projector)):
        if a.size != b.size or not np.allclose(a.K, b.K, rtol=rtol) or not np.allclose(a.t, b.t, rtol=rtol, atol=1e-6):
            return False
    return True


def twin_with_paper(system, paper: str = "auto") -> dict:
    """``to_twin(system)``, with the paper's table S3 and eqs. S1-S3 beside it (key
    ``paper_table_s3``, rows of :func:`twin_mapping.paper.compare_with_table_s3`) when ``paper``
    is "yes", or "auto" and the system is the paper's (:func:`is_papers_system`); "no": never."""
    from .errors import TwinError
    from .twin import to_twin

    if paper not in ("auto", "yes", "no"):
        raise TwinError(f"paper: expected 'auto', 'yes' or 'no', got {paper!r}")
    twin = to_twin(system)
    if paper == "yes" or (paper == "auto" and is_papers_system(system)):
        twin["paper_table_s3"] = compare_with_table_s3(twin)
    return twin


def format_twin_table(twin: dict, with_paper: bool) -> str:
    """The twin parameters as a text table; with the paper's S3/eq. S1-S3 values when asked."""
    lines = []
    if with_paper:
        rows = compare_with_table_s3(twin)
        head = f"{'device':9} {'quantity':19} {'ax':2} {'ours':>14} {'paper':>11} {'ours-paper':>12}  status"
        lines += [head, "-" * len(head)]
        for r in rows:
            lines.append(f"{r['device']:9} {r['quantity']:19} {r['axis']:2} {r['ours']:14.6f} {r['printed_text']:>11} "
                         f"{r['difference']:12.6f}  {r['status']}")
        notes = [r for r in rows if r["status"] != "reproduces"]
        if notes:
            lines.append("")
            lines += [f"! {r['device']} {r['quantity']} {r['axis']}: {r['status']}: {r['note']}" for r in notes]
        n_ok = sum(r["status"] == "reproduces" for r in rows)
        lines.append(f"{n_ok} of {len(rows)} printed values reproduce from the full-precision calibration "
                     "(S3 prints angles and locations truncated to 4 decimals)")
        from calib.system import default_system
        from .paper import check_table_s2_rotations
        ref = default_system()
        for r in check_table_s2_rotations({"camera": ref.camera.R, "projector": ref.projector.R}):
            line = (f"printed S2 {r['device']} rotation: det {r['det']:.4f}, max|R^T R - I| "
                    f"{r['max_orthonormality_error']:.4f}")
            for e in r.get("entries_off", []):
                line += (f"; entry ({e['row']},{e['col']}) printed {e['printed']:+.3f}, full precision "
                         f"{e['full_precision']:+.5f} (det {r['det_after_sign_fix']:.4f} with the sign fixed)")
            lines.append(("! " if r["max_orthonormality_error"] > 0.01 else "  ") + line)
        lines.append("")
    head = f"{'device':9} {'rotation XYZ (deg)':>30} {'location (mm)':>32} {'f (mm)':>8} {'shift':>18} {'aspect':>7}"
    lines += [head, "-" * len(head)]
    for kind in ("camera", "projector"):
        d = twin[kind]
        rot = " ".join(f"{v:9.4f}" for v in d["rotation_euler_deg"])
        loc = " ".join(f"{v:10.4f}" for v in d["location_mm"])
        shift = " ".join(f"{v:8.5f}" for v in d["shift"])
        aspect = d["pixel_aspect"][0] / d["pixel_aspect"][1]
        lines.append(f"{kind:9} {rot:>30} {loc:>32} {d['focal_length_mm']:8.4f} {shift:>18} {aspect:7.4f}")
    lines.append("")
    for kind in ("camera", "projector"):
        nr = twin[kind]["not_representable"]
        lines.append(f"not representable in Blender, {kind}: skew {nr['skew_px']:.4f} px "
                     f"(<= {nr['skew_effect_px']:.3f} px at the corners), distortion {len(nr['distortion'])} terms "
                     f"(<= {nr['distortion_effect_px']:.3f} px at the corners)")
        if "gimbal_lock" in twin[kind]:
            lines.append(f"! {kind}: {twin[kind]['gimbal_lock']}")
    for line in twin.get("repairs", []):
        lines.append(f"! repair: {line}")
    return "\n".join(lines)
