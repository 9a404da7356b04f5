"""MW / NT pairs whose beat wraps inside the projected field: traditional vs learned vs graph cut
(issue 21, item 5).

    python -m bench.beat_wrap [--work DIR] [--scenes N] [--quick] [--json OUT.json] [-q]

The pairs an outside check measured (another lab's captures: pitches 45/48, 42/48 and 42/45
projector px, 12 steps) have beat periods ``L = p1 p2 / (p2 - p1)`` = 720, 336 and 630 px, shorter
than the built-in projector's 912 px: the beat wraps inside the field. Such a pair is declared on
its **common window** (docs/unwrap.md): pattern width ``L`` px, frequencies ``L / p2`` and
``L / p1`` (15 / 16, 7 / 8, 14 / 15), so the decode is exact modulo the window.

Scenes: ``bench/data/beat_wrap.toml`` rendered by ``calib export`` (held-out meshes nefertiti,
cheburashka, suzanne before a wall or on a table; vertical fringes of pitch 48, 45 and 42 px over
the whole 912-px field, one render per scene for the three pairs; a 320x240 camera that sees the
whole projected field: ``bench/data/system_wide320.json``), at high SNR (full well 20,000 e-) and
noisy (2,300 e-, the twin test set's), cached in ``--work``. Reference: the twin's true projector
coordinate ``u``, taken modulo the window, gives the order that makes the *measured* high wrapped
phase absolute; an order counts as right when it equals the reference modulo ``f_hi`` (orders 0
and ``f_hi`` name the same fringe, the window's first and last half period).

Columns (error % of the pixels with valid inputs and a reference, the same pixels in every
column; fixed / broken against traditional MW, and the broken ones within :data:`NEAR_PX` px of a
place where the true window coordinate wraps - a wrap of the beat, or a depth step across one):
Traditional MW and NT (:func:`unwrap.temporal.decode_pair`),
Filtered 15x15 (:func:`unwrap.learned.baselines.filtered_order`), Graph cut
(:func:`unwrap.spatial_orders.graphcut_orders`, the prior's likelihood), Learned MW / NT (the
shipped model, :func:`unwrap.learned.infer.unwrap_learned`), Learned + graph cut (the network's
log-probabilities as data term), and the gated rows (:func:`unwrap.spatial_orders.gate` with the
shipped :data:`unwrap.spatial_orders.GATE` thresholds on :func:`unwrap.decision_error.error_probability`),
what ``calib unwrap --method mw [--model learned] [--spatial graphcut]`` computes.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "bench" / "data" / "beat_wrap.toml"
#: the pitch pairs (projector px) of the outside check
PAIRS = ((45, 48), (42, 48), (42, 45))
#: the exposures: name -> ``calib export --set`` overrides
EXPOSURES = {"high SNR": [], "noisy": ["effects.noise.full_well_e=2300"]}
#: camera px around a wrap of the beat counted as "beside the wrap"
NEAR_PX = 8
COLUMNS = ("Traditional MW", "Traditional NT", "Filtered 15x15", "Graph cut", "Graph cut, gated", "Learned MW",
           "Learned MW, gated", "Learned NT", "Learned + graph cut", "Learned + graph cut, gated")


def common_window(p1: float, p2: float) -> tuple[float, float, float]:
    """(window L px, f_lo, f_hi) of pitches ``p1 < p2`` px: the beat period and the pair's
    frequencies over it (periods across the window): :func:`unwrap.common_window.common_window` of
    the pair over a ``p1 p2``-px pattern."""
    from unwrap.common_window import common_window as window

    w = window(p1, p2, p1 * p2)           # (p1 and p2 periods of pitch p2 and p1 px)
    return (w["window_px"], *w["frequencies"])


def render(work: Path, scenes: int, quiet: bool) -> dict:
    """{exposure: export file} rendered once into ``work`` (``calib export``, a few minutes each)."""
    out = {}
    for name, sets in EXPOSURES.items():
        path = work / f"beat_wrap_{'hi' if not sets else 'noisy'}_{scenes}.h5"
        if not path.exists():
            print(f"rendering {CONFIG.name} ({name}, {scenes} scenes) -> {path}", file=sys.stderr, flush=True)
            cmd = [sys.executable, "-m", "sltwin.cli", "export", str(CONFIG), "-o", str(path),
                   "--set", f"export.samples={scenes}"] + [a for s in sets for a in ("--set", s)] + (["-q"] if quiet else [])
            subprocess.run(cmd, check=True)
        out[name] = path
    return out


def items(path: Path, exposure: str):
    """One item per (scene, pair): the pair's wrapped phases (rad) and modulations (full scale),
    valid, the reference order (-1 none), the window and the declared frequencies, the noise."""
    import cv2
    import h5py

    from experiments.learned_parity import capture_noise
    from unwrap._xp import TWO_PI, round_order
    from unwrap.dataset import FLAG_LOW_MODULATION, FLAG_OUT_OF_RANGE, FLAG_SATURATED
    from unwrap.dataset_schema import decode_modulation, decode_phase, read_attrs

    with h5py.File(path, "r") as h5:
        a = read_attrs(h5)
        freqs = [float(f) for f in h5["v"].attrs["frequencies"]]
        width = float(a["widths"]["v"])
        steps = int(a["steps"] if not isinstance(a["steps"], list) else a["steps"][-1])
        noise = capture_noise(path, "v", (freqs[0], freqs[-1]))
        bad = FLAG_LOW_MODULATION | FLAG_SATURATED | FLAG_OUT_OF_RANGE
        for s in range(h5["v/phase"].shape[0]):
            masks = h5["masks"][s]
            lit = ((masks & 2) > 0) & ((masks & 4) == 0)           # lit, not in a cast shadow
            u = h5["v/coordinate"][s].astype(np.float64)
            for p1, p2 in PAIRS:
                L, f_lo, f_hi = common_window(p1, p2)
                i_lo = int(np.argmin([abs(f - width / p2) for f in freqs]))
                i_hi = int(np.argmin([abs(f - width / p1) for f in freqs]))
                phi = {i: decode_phase(h5["v/phase"][s, i]) for i in (i_lo, i_hi)}
                mod = {i: decode_modulation(h5["v/modulation"][s, i]) for i in (i_lo, i_hi)}
                valid = lit & np.isfinite(u) & ((h5["v/flags"][s, i_lo] & bad) == 0) & ((h5["v/flags"][s, i_hi] & bad) == 0)
                uw = np.remainder(np.nan_to_num(u) + 0.5, L) - 0.5             # the window's coordinate
                ref = round_order((TWO_PI * f_hi * uw / L - phi[i_hi]) / TWO_PI)
                jump = np.zeros(u.shape, bool)        # pixels beside a wrap of the beat (the window's edge)
                fin = np.isfinite(u)
                jx = (np.abs(np.diff(uw, axis=1)) > L / 2) & fin[:, 1:] & fin[:, :-1]
                jy = (np.abs(np.diff(uw, axis=0)) > L / 2) & fin[1:, :] & fin[:-1, :]
                jump[:, 1:] |= jx
                jump[:, :-1] |= jx
                jump[1:, :] |= jy
                jump[:-1, :] |= jy
                near = cv2.dilate((jump & valid).astype(np.uint8), np.ones((2 * NEAR_PX + 1,) * 2, np.uint8)) > 0
                yield dict(name=f"{p1}/{p2} {exposure} #{s}", pair=f"{p1}/{p2}", exposure=exposure,
                           phase_low=phi[i_lo], phase_high=phi[i_hi], m_low=mod[i_lo], m_high=mod[i_hi], valid=valid,
                           ref=np.where(valid, ref, -1).astype(np.int64), freqs=(f_lo, f_hi), width=L,
                           field=width, steps=steps, sigma_I=noise["sigma_I"],
                           near_wrap=near, beyond=float((u[valid] >= L - 0.5).mean()) if valid.any() else 0.0)


def decode(it) -> tuple[dict, np.ndarray]:
    """{column: order (H, W) int64}, and the pixels every column decoded (valid, with a reference)."""
    from unwrap.decision_error import error_probability
    from unwrap.learned.baselines import filtered_order
    from unwrap.learned.infer import unwrap_learned
    from unwrap.spatial_orders import GATE, gate, graphcut_orders, phase_noise
    from unwrap.temporal import decode_pair

    f, W = it["freqs"], it["width"]
    s_lo = phase_noise(it["m_low"], it["steps"], it["sigma_I"])
    s_hi = phase_noise(it["m_high"], it["steps"], it["sigma_I"])
    out = {}
    prior, n, ok = decode_pair("mw", it["phase_low"], it["phase_high"], *f, W, it["valid"])
    out["Traditional MW"] = n
    out["Traditional NT"] = decode_pair("nt", it["phase_low"], it["phase_high"], *f, W, it["valid"])[1]
    out["Filtered 15x15"] = filtered_order("mw", it["phase_low"], it["phase_high"], f, ok, width=W)
    gc = graphcut_orders("mw", it["phase_low"], it["phase_high"], f, ok, s_lo, s_hi, width=W)
    p_wrong = error_probability(gc.p_wrong_traditional, gc.prior, ok, it["m_low"], it["m_high"])
    out["Graph cut"] = gc.order
    out["Graph cut, gated"] = gate(gc.order, n, ok, p_wrong, **GATE["Graph cut"])
    for m in ("mw", "nt"):
        r = unwrap_learned(m, it["phase_low"], it["phase_high"], it["m_low"], it["m_high"], ok, f, width=W,
                           log_probs=m == "mw")
        out[f"Learned {m.upper()}"] = r.order
        if m == "mw":
            out["Learned MW, gated"] = gate(r.order, n, ok, p_wrong, confidence=r.confidence, **GATE["Learned"])
            lgc = graphcut_orders("mw", it["phase_low"], it["phase_high"], f, ok, s_lo, s_hi, width=W,
                                  cost=-r.log_probs)
            c = np.clip(lgc.correction + 2, 0, 4)
            conf = np.exp(np.take_along_axis(r.log_probs, c[None], 0)[0])
            out["Learned + graph cut"] = lgc.order
            out["Learned + graph cut, gated"] = gate(lgc.order, n, ok, p_wrong, confidence=conf,
                                                     **GATE["Learned + graph cut"])
    return out, ok & (it["ref"] >= 0)


def wrong(order, ref, f_hi: float) -> np.ndarray:
    """Orders that differ from the reference modulo the window (``f_hi`` orders; invalid = wrong)."""
    kw = int(round(f_hi))
    return (order < 0) | (np.remainder(order - ref, kw) != 0)


def run(work: Path, scenes: int, quiet: bool = False) -> dict:
    """{(pair, exposure): {"pixels", "beyond", column: [wrong, fixed, broken, broken within
    :data:`NEAR_PX` px of a wrap of the beat]}} over the scenes."""
    from tqdm import tqdm

    files = render(work, scenes, quiet)
    rows = {}
    todo = [(e, p) for e, p in files.items()]
    for exposure, path in todo:
        its = list(items(path, exposure))
        for it in tqdm(its, desc=f"decoding ({exposure})", disable=quiet, file=sys.stderr):
            out, m = decode(it)
            key = (it["pair"], exposure)
            row = rows.setdefault(key, {"pixels": 0, "beyond": [], **{c: [0, 0, 0, 0] for c in COLUMNS}})
            row["pixels"] += int(m.sum())
            row["beyond"].append(it["beyond"])
            bad_t = wrong(out["Traditional MW"], it["ref"], it["freqs"][1]) & m
            for c in COLUMNS:
                bad = wrong(out[c], it["ref"], it["freqs"][1]) & m
                row[c][0] += int(bad.sum())
                row[c][1] += int((bad_t & ~bad).sum())
                row[c][2] += int((bad & ~bad_t).sum())
                row[c][3] += int((bad & ~bad_t & it["near_wrap"]).sum())
    return rows


def table(rows: dict) -> str:
    """The markdown table: error % per column, then fixed / broken vs traditional MW."""
    head = "| pair, exposure (pixels; lit beyond one window) | " + " | ".join(COLUMNS) + " |"
    lines = [head, "|" + "---|" * (len(COLUMNS) + 1)]
    for (pair, exposure), r in rows.items():
        L = common_window(*map(float, pair.split("/")))[0]
        lines.append(f"| {pair} px (window {L:.0f} px), {exposure} ({r['pixels']:,}; {100 * np.mean(r['beyond']):.0f} %) | "
                     + " | ".join(f"{100 * r[c][0] / max(r['pixels'], 1):.3f}" for c in COLUMNS) + " |")
    for (pair, exposure), r in rows.items():
        lines.append(f"| fixed / broken, {pair} {exposure} | "
                     + " | ".join("-" if c == "Traditional MW" else f"{r[c][1]:,} / {r[c][2]:,}" for c in COLUMNS) + " |")
    for (pair, exposure), r in rows.items():
        lines.append(f"| broken within {NEAR_PX} px of a beat wrap, {pair} {exposure} | "
                     + " | ".join("-" if c == "Traditional MW" else f"{r[c][3]:,}" for c in COLUMNS) + " |")
    worse = {c: sum(r[c][0] > r["Traditional MW"][0] for r in rows.values()) for c in COLUMNS[1:]}
    lines.append("")
    lines.append("worse than traditional MW in (of %d cases): " % len(rows)
                 + ", ".join(f"{c} {n}" for c, n in worse.items()))
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.beat_wrap", description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", default="/tmp/sltwin_bench_beat_wrap", help="cache of the rendered scenes")
    ap.add_argument("--scenes", type=int, default=6, help="scenes per exposure (default 6)")
    ap.add_argument("--json", help="also write the counts as JSON here")
    ap.add_argument("--quick", action="store_true", help="one scene per exposure")
    ap.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    args = ap.parse_args(argv)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    rows = run(work, 1 if args.quick else args.scenes, args.quiet)
    print(table(rows))
    if args.json:
        from unwrap.safe_output import write_text
        write_text(args.json, json.dumps({f"{p} {e}": r for (p, e), r in rows.items()}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
