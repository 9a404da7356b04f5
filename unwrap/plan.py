"""Choose frequencies and step counts: predicted fringe-order error rate vs number of images.

SYNOPSIS

    >>> from unwrap.plan import plan_fringes
    >>> rows = plan_fringes(["mf:1,8,48"], steps=(3, 12), sigma=2.0, modulation=60.0)
    >>> [(r["set"], r["steps"], r["images"]) for r in rows]
    [('mf:1,8,48', 3, 9), ('mf:1,8,48', 12, 36)]
"""
from __future__ import annotations

import math

from .errors import UnwrapError
from .methods import METHODS
from .reliability import error_rate, phase_sigma
from .temporal import check_mf_ladder, check_mw_set, check_nt_pair

#: Candidate sets shown by default (the paper's 1, 8, 48 ladder and common alternatives).
DEFAULT_SETS = ("mf:1,8,48", "mf:1,4,16,64", "mf:1,12,96", "mf:1,96", "mw:48,47", "mw:96,95",
                "mw:70,64,59", "nt:47,48", "nt:95,96", "gray:32", "gray:64")

#: Method names, as ``calib unwrap --method`` spells them; ``gray`` is complementary Gray code
#: (one code period per fringe period plus a half-period bit, SLMaster's), whose reliability
#: model exists. ``cgray`` is accepted for it, as earlier versions printed it.


def parse_set(text: str):
    """``"mf:1,8,48"`` -> ("mf", [1.0, 8.0, 48.0]); refused (UnwrapError) exactly when ``calib unwrap``
    would refuse the ladder (:func:`unwrap.temporal.check_mf_ladder`, ``check_mw_set``,
    ``check_nt_pair``; Gray code: one frequency > 0)."""
    try:
        method, freqs = text.split(":")
        f = [float(v) for v in freqs.split(",")]
    except ValueError:
        raise UnwrapError(f"frequency set {text!r}: expected METHOD:F1,F2,... "
                          "(e.g. mf:1,8,48, mw:70,64,59, nt:47,48, gray:32)") from None
    method = "gray" if method == "cgray" else method
    if method not in METHODS:
        raise UnwrapError(f"frequency set {text!r}: method must be one of {', '.join(METHODS)}")
    try:
        if method == "mf":
            check_mf_ladder(f)
        elif method == "mw":
            check_mw_set(f)
        elif method == "nt":
            check_nt_pair(f)
        elif len(f) != 1 or not f[0] > 0:
            raise UnwrapError(f"Gray code takes one fringe frequency > 0, got {f}")
    except UnwrapError as exc:
        raise UnwrapError(f"frequency set {text!r}: {exc}") from None
    return method, f


def images_needed(method: str, freqs, steps: int) -> int:
    """Frames to capture per orientation (complementary Gray code: log2(f) + 1 code frames)."""
    if method == "gray":
        return steps + int(math.ceil(math.log2(max(freqs)))) + 1
    return steps * len(freqs)


def plan_fringes(sets=DEFAULT_SETS, steps=(3, 4, 6, 12), *, sigma: float, modulation: float):
    """Rows {set, method, frequencies, steps, images, sigma_phi, error_rate} for every set x N."""
    rows = []
    for text in sets:
        method, f = parse_set(text)
        for n in steps:
            s_phi = phase_sigma(sigma, n, modulation)
            rows.append({"set": text, "method": method, "frequencies": f, "steps": n,
                         "images": images_needed(method, f, n), "sigma_phi": s_phi,
                         "error_rate": error_rate("cgray" if method == "gray" else method, f, s_phi)})
    return rows


def format_table(rows, max_error_rate: float | None = None) -> str:
    lines = ["| set | steps N | images | sigma_phi [rad] | predicted k error rate |",
             "|---|---:|---:|---:|---:|"]
    for r in rows:
        flag = " (over limit)" if max_error_rate is not None and r["error_rate"] > max_error_rate else ""
        lines.append(f"| {r['set']} | {r['steps']} | {r['images']} | {r['sigma_phi']:.4f} | "
                     f"{r['error_rate']:.3g}{flag} |")
    return "\n".join(lines)
