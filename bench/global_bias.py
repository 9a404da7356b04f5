"""The global-light bound on the coarse phase's bias in the graph cut's data term (issue 21).

    python -m bench.global_bias [--cycles-dir DIR] [--work DIR] [--json OUT.json] [--calibrate [--tight]] [--no-twin]
                                [--quick]

:mod:`unwrap.global_light` separates direct and global light from the high frequency's offset and
modulation and bounds the bias of the coarse phase; ``graphcut_orders(..., bias_bound=...)``
widens the prior's likelihood by ``bias_scale`` x that bound. Rows (every row on the same pixels;
error % of the pixels with a reference; fixed / broken against traditional):

- Traditional, Graph cut (the shipped data term), Graph cut + global bound, and both gated
  (:func:`unwrap.spatial_orders.gate` with the shipped decision error model and threshold);
- drop rankings of the traditional decode (2 % / 10 % dropped): modulation, the reliability
  model, the decision error model, and the global / direct ratio ``rho`` and the bound in fringes.

Sources: the Cycles test set (``--cycles-dir``: ``cycles_test.h5`` and its ``frames/`` cache; the
offsets A, which the file does not store, are rebuilt from the cached Cycles basis frames with
:mod:`experiments.cycles_testset`'s own functions - nothing is rendered - and checked against
the file's phases), the pyramid (v, h) and SLStudio's skull (offsets from their frames), and the
twin test set (offsets re-rendered per scene, checked against the export's phases).
``--calibrate``: the bias scale on the validation scenes only (the 6 interreflection scenes of
``bench/data/decision_error_val.toml`` and the 6 noise-dominated ones of ``spatial_val.toml``,
rendered into ``--work``): the least error on their pooled pixels such that no scene gets more
wrong orders than traditional (:func:`calibrate_scale`).
The Cycles rows also get the failure analysis of :func:`patch_analysis`. ``--quick``: the
pyramid's vertical orientation only, shipped scale.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from unwrap.safe_output import atomic_path, write_text

SCALE_GRID = (0.0, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 4.0)
DROPS = (0.02, 0.10)


# ---------------------------------------------------------------- offsets for each source
def _attach(it, a_low, a_high, phase_low, phase_high, what: str):
    """Put the offsets (full scale) into item ``it`` after checking that ``phase_*`` (rad) are the
    item's phases (the same decode: wrapped difference <= 1e-3 rad at 99.9 % of its valid pixels)."""
    v = it["valid"]
    for name, p in (("phase_low", phase_low), ("phase_high", phase_high)):
        d = np.abs(np.angle(np.exp(1j * (it[name] - np.nan_to_num(p)))))[v]
        if d.size and np.mean(d > 1e-3) > 1e-3:
            raise RuntimeError(f"{what}: the rebuilt {name} differs from the item's at {100 * np.mean(d > 1e-3):.2f} % "
                               "of the valid pixels: not the same capture")
    it["a_low"], it["a_high"] = np.asarray(a_low, np.float64), np.asarray(a_high, np.float64)
    return it


def cycles_items(cycles_dir: Path, f: float):
    """Items of the Cycles test set's MF pair (1, f) with offsets rebuilt from the frame cache."""
    from bench.cycles_testset import file_items
    from experiments import cycles_testset as ct
    from unwrap.phase_shift import wrapped_phase

    items = file_items(cycles_dir / "cycles_test.h5", f)
    system = ct.testset_system((items[0]["valid"].shape[1], items[0]["valid"].shape[0]))
    _, basis, coef = ct.patterns_and_basis(system)
    top = float((1 << ct.BITS) - 1)
    j_hi = ct.FREQUENCIES.index(float(f))
    for i, it in enumerate(items):
        p = it["params"]
        sc = ct.build_scene(it["scene"])
        seeds = tuple(range(int(p.get("unit_seeds", 1))))
        st = ct.cycles_stacks(sc, system, coef, basis, samples=int(p["samples"]), bounces=int(p["bounces"]),
                              threads=2, cache_dir=cycles_dir, unit_seeds=seeds)
        counts = ct.sensor(st["gi"], seed=int(p["noise"]["seed"]))
        w = [wrapped_phase(counts[j * ct.STEPS:(j + 1) * ct.STEPS], min_modulation=ct.MIN_MODULATION * top,
                           saturation=top) for j in (0, j_hi)]
        _attach(it, w[0].A / top, w[1].A / top, w[0].phase, w[1].phase, f"Cycles {it['scene']}")
        it["direct_phase_low"] = np.asarray(wrapped_phase(st["direct"][:ct.STEPS], saturation=None).phase)
    return items


def skull_items(work: Path):
    """SLStudio's skull (bench.spatial_unwrap) with the offsets of its 3-step frames."""
    from bench.spatial_unwrap import SHARED, _skull_items
    from unwrap.capture import FrameReader, load_capture
    from unwrap.phase_shift import wrapped_phase

    items = _skull_items(work)
    if not items:
        return []
    cap = load_capture(SHARED / "slstudio-ps2x3-calib" / "skull_2x3")
    reader = FrameReader(cap.camera_size)
    for it in items:
        o = it["name"].split()[-1]
        sets = sorted(cap.orientations[o].sets, key=lambda s: s.frequency)
        w = [wrapped_phase(reader.stack(s.files), s.shifts) for s in (sets[0], sets[-1])]
        top = 255.0
        _attach(it, w[0].A / top, w[1].A / top, w[0].phase, w[1].phase, "skull")
    return items


def twin_items(work: Path, which: str = "test"):
    """The twin set of bench.spatial_unwrap with offsets from re-rendering each scene as ``calib
    export`` does (cached in ``work`` as ``offsets_{which}_{i}.npz``)."""
    from bench.spatial_unwrap import ROOT, _render_bias_scene, _twin_items
    from synth.export.config import load_config
    from synth.export.dataset import base_system

    items = _twin_items(work, which)
    cfg = load_config(ROOT / "bench" / "data" / f"spatial_{which}.toml")
    system, _ = base_system(cfg)
    for i, it in enumerate(items):
        path = work / f"offsets_{which}_{i}.npz"
        if not path.exists():
            print(f"rendering twin {which} scene {i + 1}/{len(items)} for its offsets -> {path}", file=sys.stderr,
                  flush=True)
            r = _render_bias_scene(cfg, system, i, interreflection=False)
            with atomic_path(path) as tmp:     # a killed run must not leave a truncated cache
                np.savez_compressed(tmp, **{k: r[k] for k in ("a_low", "a_high", "phase_low", "phase_high")})
        z = np.load(path)
        _attach(it, z["a_low"], z["a_high"], z["phase_low"], z["phase_high"], f"twin {which} #{i}")
    return items


# ---------------------------------------------------------------- decoding
def bound_fringes(it, kappa=None, *, unit_modulation: bool = False):
    """(GlobalBias, bound in fringes of the item's high frequency); ``unit_modulation``: tighten it
    with the unit frequency's modulation (``bias_bound(modulation_low=)``)."""
    from unwrap.global_light import bias_bound

    g = bias_bound(it["a_high"], it["m_high"], it["valid"], kappa=kappa, offset_low=it["a_low"],
                   modulation_low=it["m_low"] if unit_modulation else None)
    return g, g.fringes(*it["freqs"])


def decode(it, scale: float, *, shipped=True, tight=True, loose=True, max_correction=None):
    """{row: orders}, extra maps; the shipped graph cut and the graph cut with the bound (``loose``:
    from the high frequency alone, the shipped choice; ``tight``: with the unit modulation too)."""
    from bench.spatial_unwrap import _sigmas
    from unwrap.decision_error import error_probability
    from unwrap.spatial_orders import DEFAULTS, GATE, gate, graphcut_orders
    from unwrap.temporal import decode_pair

    s_lo, s_hi = _sigmas(it)
    prior, n, ok = decode_pair("mf", it["phase_low"], it["phase_high"], *it["freqs"], it["width"], it["valid"])
    g, bf = bound_fringes(it)
    _, bf_tight = bound_fringes(it, unit_modulation=True)
    out, ms = {"Traditional": n}, {}
    kw = dict(width=it["width"], smoothness=DEFAULTS["smoothness"], outlier=DEFAULTS["outlier"],
              sigma_floor=DEFAULTS["sigma_floor"])
    res = {}
    if shipped:
        res["Graph cut"] = graphcut_orders("mf", it["phase_low"], it["phase_high"], it["freqs"], ok, s_lo, s_hi, **kw)
    kw["max_correction"] = DEFAULTS["bias_max_correction"] if max_correction is None else max_correction
    if loose:
        res["Graph cut + global bound"] = graphcut_orders("mf", it["phase_low"], it["phase_high"], it["freqs"], ok,
                                                          s_lo, s_hi, bias_bound=bf, bias_scale=scale, **kw)
    if tight:
        res["Graph cut + global bound (B_1)"] = graphcut_orders("mf", it["phase_low"], it["phase_high"], it["freqs"],
                                                                ok, s_lo, s_hi, bias_bound=bf_tight, bias_scale=scale,
                                                                **kw)
    r0 = next(iter(res.values()))
    p_bias = error_probability(r0.p_wrong_traditional, r0.prior, ok, it["m_low"], it["m_high"])
    from unwrap.decision_error import MODEL_GLOBAL
    p_global = None if MODEL_GLOBAL is None else error_probability(r0.p_wrong_traditional, r0.prior, ok, it["m_low"],
                                                                   it["m_high"], global_ratio=g.ratio)
    for k, r in res.items():
        out[k], ms[k] = r.order, 1e3 * r.seconds
        out[f"{k}, gated"] = gate(r.order, n, ok, p_bias, **GATE["Graph cut"])
    extra = {"valid": ok, "prior": prior, "p_wrong": r0.p_wrong_traditional, "p_wrong_bias": p_bias,
             "p_wrong_global": p_global, "rho": g.ratio,
             "bound_fringes": bf, "kappa": g.kappa, "notes": g.notes, "results": res}
    return out, ms, extra


def score(items, scale: float, *, analyse: bool = False, max_correction=None):
    """Pooled rows {row: [wrong, counted, fixed, broken]}, drop curves, kappas, and (``analyse``)
    the patch analysis of the remaining graph-cut errors."""
    from unwrap.learned.metrics import keep_drop_curve

    rows, curves, kappas, ana, ms = {}, {}, [], {}, {}
    for it in items:
        out, t, ex = decode(it, scale, max_correction=max_correction)
        m = ex["valid"] & (it["ref"] >= 0)
        right_t = out["Traditional"] == it["ref"]
        for row, k in out.items():
            acc = rows.setdefault(row, [0, 0, 0, 0])
            acc[0] += int((k != it["ref"])[m].sum())
            acc[1] += int(m.sum())
            acc[2] += int((~right_t & (k == it["ref"]))[m].sum())
            acc[3] += int((right_t & (k != it["ref"]))[m].sum())
        for row, v in t.items():
            ms.setdefault(row, []).append(v)
        kappas.append(ex["kappa"])
        wrong = ~right_t[m]
        margin = 0.5 - np.abs(ex["prior"] - np.rint(ex["prior"]))
        ranks = [("modulation", np.minimum(it["m_low"], it["m_high"])[m]), ("reliability model", -ex["p_wrong"][m]),
                 ("decision error model", -ex["p_wrong_bias"][m]), ("global / direct ratio", -ex["rho"][m]),
                 ("global bound minus margin", -(ex["bound_fringes"] - margin)[m])]
        if ex["p_wrong_global"] is not None:
            ranks.append(("decision error model with the global ratio", -ex["p_wrong_global"][m]))
        for name, sc in ranks:
            c = curves.setdefault(name, [[], []])
            c[0].append(sc), c[1].append(wrong)
        if analyse:
            for row in ("Graph cut", "Graph cut + global bound", "Graph cut + global bound (B_1)"):
                a = patch_analysis(it, ex["results"][row], out[row])
                acc = ana.setdefault(row, {})
                for k, v in a.items():
                    acc[k] = acc.get(k, 0) + v
    curves = {k: [r for _, r in keep_drop_curve(np.concatenate(s), np.concatenate(w), (0.0,) + DROPS)]
              for k, (s, w) in curves.items()}
    return {"rows": rows, "curves": curves, "kappa": kappas, "analysis": ana,
            "ms": {k: float(np.median(v)) for k, v in ms.items()}}


# ---------------------------------------------------------------- why the graph cut fails
def patch_analysis(it, res, order, min_patch: int = 100) -> dict:
    """Why the graph cut keeps its remaining wrong orders: 4-connected patches of wrong pixels (one
    wrong correction) of >= ``min_patch`` px; their boundary (4-neighbour pairs patch -> outside)
    split into: to an invalid pixel, a cut smoothness edge (depth-edge criteria, w = 0) to a valid
    pixel, a live edge to a right pixel, a live edge to a pixel wrong otherwise; and, per patch, the
    exact change of the shipped energy if the patch alone took its true orders: data (nats, > 0:
    the data prefer the wrong orders) and smoothness (> 0: the true orders make more 2 pi jumps
    across the boundary than the wrong ones - the patch is wrap-consistent with its surroundings,
    the high phase itself jumps there - or its wrong neighbours stay wrong). The solution being the
    exact minimum, data + smoothness >= 0 for every patch. The shipped energy has labels +-2 only: a
    patch pixel whose true or current correction lies beyond them is priced at the nearest of them
    (``px_clipped`` counts such pixels; their data change is then not exact). Over the image: the wrong pixels whose
    true order is beyond the shipped label range, and the 2 pi jumps on live edges of the true and
    of the row's orders (pixels with a reference)."""
    import cv2

    from bench.spatial_unwrap import _sigmas
    from unwrap.spatial_orders import DEFAULTS, MAX_CORRECTION, edge_weights, prior_data_cost, prior_sigma

    lam = DEFAULTS["smoothness"]
    v = res.valid & (it["ref"] >= 0)
    err = np.where(v, order - it["ref"], 0)
    wx, wy = edge_weights(it["phase_high"], res.valid, weight=lam, prior=res.prior)
    s_lo, s_hi = _sigmas(it)
    sig = np.sqrt(prior_sigma("mf", it["freqs"], s_lo, s_hi) ** 2 + DEFAULTS["sigma_floor"] ** 2)
    cost = prior_data_cost(res.prior, res.order_traditional, sig, res.valid, frequency_high=it["freqs"][1],
                           outlier=DEFAULTS["outlier"])
    phi = np.where(res.valid, it["phase_high"], 0.0)

    def smooth(o):
        Phi = phi + 2 * math.pi * o
        return sum((w * np.abs(np.rint(np.diff(Phi, axis=ax) / (2 * math.pi)))).sum() for ax, w in ((1, wx), (0, wy)))

    def jumps(o):        # 2 pi jumps on live edges between pixels that both have a reference
        Phi = phi + 2 * math.pi * np.where(v, o, 0)
        both = {1: v[:, :-1] & v[:, 1:], 0: v[:-1] & v[1:]}
        return int(sum(np.abs(np.rint(np.diff(Phi, axis=ax) / (2 * math.pi)))[(w > 0) & both[ax]].sum()
                       for ax, w in ((1, wx), (0, wy))))

    out = {"patches": 0, "wrong_in_patches": 0, "wrong": int((err != 0).sum()), "b_invalid": 0, "b_cut": 0,
           "b_live_right": 0, "b_live_wrong": 0, "data_nats": 0.0, "smooth_nats": 0.0, "held_by_data": 0,
           "held_by_smoothness": 0, "px_held_by_data": 0, "px_held_by_smoothness": 0,
           "beyond_labels": int(((err != 0) & (np.abs(it["ref"] - res.order_traditional) > MAX_CORRECTION)).sum()),
           "jumps_true": jumps(it["ref"]), "jumps_now": jumps(order), "px_clipped": 0}
    base_s = smooth(np.where(res.valid, order, 0))
    for e in np.unique(err[err != 0]):
        n, lab, st, _ = cv2.connectedComponentsWithStats((err == e).astype(np.uint8), connectivity=4)
        for k in range(1, n):
            if st[k, cv2.CC_STAT_AREA] < min_patch:
                continue
            P = lab == k
            npx = int(P.sum())
            out["patches"] += 1
            out["wrong_in_patches"] += npx
            for axis, w in ((1, wx), (0, wy)):
                a = P[:, :-1] if axis == 1 else P[:-1]
                b = P[:, 1:] if axis == 1 else P[1:]
                for inside, other, sl_o in ((a, b, (slice(None), slice(1, None)) if axis == 1 else (slice(1, None),)),
                                            (b, a, (slice(None), slice(None, -1)) if axis == 1 else (slice(None, -1),))):
                    edge = inside & ~other
                    vo, eo = res.valid[sl_o], err[sl_o]
                    out["b_invalid"] += int((edge & ~vo).sum())
                    out["b_cut"] += int((edge & vo & (w == 0)).sum())
                    out["b_live_right"] += int((edge & vo & (w > 0) & (eo == 0)).sum())
                    out["b_live_wrong"] += int((edge & vo & (w > 0) & (eo != 0)).sum())
            raw_now, raw_true = (order - res.order_traditional)[P], (it["ref"] - res.order_traditional)[P]
            out["px_clipped"] += int(((np.abs(raw_now) > MAX_CORRECTION) | (np.abs(raw_true) > MAX_CORRECTION)).sum())
            c_now = np.clip(raw_now + MAX_CORRECTION, 0, 2 * MAX_CORRECTION)
            c_true = np.clip(raw_true + MAX_CORRECTION, 0, 2 * MAX_CORRECTION)
            idx = np.arange(npx)
            d = float((cost[:, P][c_true, idx] - cost[:, P][c_now, idx]).sum())
            flipped = np.where(P, it["ref"], np.where(res.valid, order, 0))
            sm = float(smooth(flipped) - base_s)
            out["data_nats"] += d
            out["smooth_nats"] += sm
            key = "smoothness" if sm >= 0 else "data"
            out[f"held_by_{key}"] += 1
            out[f"px_held_by_{key}"] += npx
    return out


def fit_global(items) -> dict:
    """The decision error model with the global / direct ratio as a sixth feature
    (:data:`unwrap.decision_error.MODEL_GLOBAL`), pooled over the items (validation scenes only)."""
    from bench.spatial_unwrap import item_features
    from unwrap.decision_error import FEATURES, GLOBAL_FEATURE, fit
    from unwrap.temporal import decode_pair

    Xs, ys = [], []
    for it in items:
        X, y, _ = item_features(it)
        _, _, ok = decode_pair("mf", it["phase_low"], it["phase_high"], *it["freqs"], it["width"], it["valid"])
        g, _ = bound_fringes(it)
        Xs.append(np.column_stack([X, np.log1p(g.ratio[ok & (it["ref"] >= 0)])])), ys.append(y)
    X, y = np.concatenate(Xs), np.concatenate(ys)
    n_bias = sum("bias-val" in it["name"] for it in items)
    return fit(X, y, names=FEATURES + (GLOBAL_FEATURE,),
               note=f"bench.decision_error_fit --global: {len(items)} validation scenes ({len(items) - n_bias} of "
                    f"spatial_val.toml, {n_bias} of decision_error_val.toml with interreflection), {len(y)} pixels")


# ---------------------------------------------------------------- calibration (validation only)
def calibrate_scale(items, grid=SCALE_GRID, *, tight: bool = False, max_correction=None):
    """The bias scale with the least pooled error on the validation items such that no item gets
    more wrong orders than traditional (the rule of the energy's other constants: least validation
    error; scale 0 is the shipped term); prints the grid, per item."""
    from unwrap.temporal import decode_pair

    trad = []
    for it in items:
        _, n, ok = decode_pair("mf", it["phase_low"], it["phase_high"], *it["freqs"], it["width"], it["valid"])
        trad.append(int((n != it["ref"])[ok & (it["ref"] >= 0)].sum()))
    print(f"  traditional: {sum(trad)} wrong (per scene {trad})", file=sys.stderr, flush=True)
    best = None
    for s in grid:
        per = []
        for it in items:
            out, _, ex = decode(it, s, shipped=False, tight=tight, loose=not tight, max_correction=max_correction)
            m = ex["valid"] & (it["ref"] >= 0)
            row = "Graph cut + global bound" + (" (B_1)" if tight else "")
            per.append(int((out[row] != it["ref"])[m].sum()))
        ok = all(p <= t for p, t in zip(per, trad))
        print(f"  bias scale {s:g}: {sum(per)} wrong (per scene {per}){'' if ok else ' - worse than traditional'}",
              file=sys.stderr, flush=True)
        if ok and (best is None or sum(per) < best[0]):
            best = (sum(per), s)
    if best is None:
        raise RuntimeError(f"no bias scale of {grid} leaves every validation scene at or below traditional")
    return best[1]


def table(name, R) -> str:
    t = R["rows"]["Traditional"]
    rt = t[0] / max(t[1], 1)
    L = [f"\n### {name} ({t[1]:,} pixels; kappa {', '.join(f'{k:.3f}' for k in R['kappa'])})\n",
         "| row | error % | traditional / row | fixed | broken | ms |", "|---|---:|---:|---:|---:|---:|"]
    for row, (w, c, fx, br) in R["rows"].items():
        r = w / max(c, 1)
        ms = R["ms"].get(row)
        L.append(f"| {row} | {100 * r:.3f} | {rt / r if r else float('inf'):.2f}x | {fx:,} | {br:,} | "
                 f"{'' if ms is None else f'{ms:.0f}'} |")
    L += ["", "| traditional decode ranked by | 0 % | 2 % dropped | 10 % dropped |", "|---|---:|---:|---:|"]
    for k, c in R["curves"].items():
        L.append(f"| {k} | " + " | ".join(f"{100 * v:.3f}" for v in c) + " |")
    for row, a in R.get("analysis", {}).items():
        b = a["b_invalid"] + a["b_cut"] + a["b_live_right"] + a["b_live_wrong"]
        L.append(f"\n{row}: {a['wrong']:,} wrong, {a['wrong_in_patches']:,} in {a['patches']} patches >= 100 px; their "
                 f"boundary: {100 * a['b_invalid'] / max(b, 1):.1f} % to invalid px, {100 * a['b_cut'] / max(b, 1):.1f} % "
                 f"cut (depth-edge criteria), {100 * a['b_live_right'] / max(b, 1):.1f} % live to right px, "
                 f"{100 * a['b_live_wrong'] / max(b, 1):.1f} % live to other wrong px. Giving each patch its true orders "
                 f"(shipped energy): data +{a['data_nats']:.0f} nats, smoothness {a['smooth_nats']:+.0f} nats in total; "
                 f"{a['held_by_smoothness']} patches ({a['px_held_by_smoothness']:,} px) are wrap-consistent with their "
                 f"surroundings (the true orders cost smoothness too), {a['held_by_data']} ({a['px_held_by_data']:,} px) "
                 f"are held by the data alone ({a['px_clipped']:,} patch px priced at a clipped label). "
                 f"{a['beyond_labels']:,} wrong px need a correction beyond the shipped "
                 f"+-2; the true orders make {a['jumps_true']:,} jumps on live edges, this row's {a['jumps_now']:,}")
    return "\n".join(L)


def main(argv=None) -> int:
    from bench.spatial_unwrap import _pyramid_items, bias_items
    from unwrap.spatial_orders import DEFAULTS

    ap = argparse.ArgumentParser(prog="python -m bench.global_bias", description=__doc__.split("\n")[0])
    ap.add_argument("--cycles-dir", default=None, help="folder of cycles_test.h5 and its frames/ cache")
    ap.add_argument("--work", default="/tmp/sltwin_bench_spatial", help="cache of exports / renders")
    ap.add_argument("--calibrate", action="store_true", help="choose the bias scale on the validation scenes")
    ap.add_argument("--tight", action="store_true", help="with --calibrate: for the bound tightened by the unit "
                                                        "frequency's modulation")
    ap.add_argument("--max-correction", type=int, default=None,
                    help="label range K of the bound rows (default: the shipped DEFAULTS bias_max_correction)")
    ap.add_argument("--scale", type=float, default=None, help="bias scale (default: the shipped DEFAULTS)")
    ap.add_argument("--no-twin", action="store_true")
    ap.add_argument("--quick", action="store_true", help="the pyramid's vertical orientation only")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    scale = DEFAULTS["bias_scale"] if args.scale is None else args.scale
    if args.calibrate:
        scale = calibrate_scale(bias_items(work) + twin_items(work, "val"), tight=args.tight,
                                max_correction=args.max_correction)
        print(f"calibrated bias scale (validation scenes): {scale:g}", flush=True)
    print(f"bias scale {scale:g}; graph cut smoothness {DEFAULTS['smoothness']:g}, outlier {DEFAULTS['outlier']:g}")
    sources = []
    if args.cycles_dir:
        d = Path(args.cycles_dir)
        sources += [(f"Cycles set, f = {f:g}", lambda f=f: cycles_items(d, f), True) for f in (48.0, 96.0)]
    sources += [("pyramid v", lambda: _pyramid_items(("v",)), False)]
    if not args.quick:
        sources += [("pyramid h", lambda: _pyramid_items(("h",)), False), ("skull", lambda: skull_items(work), False)]
    if not (args.no_twin or args.quick):
        sources.append(("twin test", lambda: twin_items(work, "test"), False))
    results = {}
    for name, load, analyse in sources:
        t0 = time.perf_counter()
        items = load()
        if not items:
            print(f"\n({name}: not found, skipped)")
            continue
        results[name] = score(items, scale, analyse=analyse, max_correction=args.max_correction)
        print(table(name, results[name]) + f"\n({time.perf_counter() - t0:.0f} s)", flush=True)
    if args.json:
        write_text(Path(args.json), json.dumps({"scale": scale, "results": results}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
