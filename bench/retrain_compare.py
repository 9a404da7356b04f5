"""Two learned models on the same pixels: the shipped one and a retrained candidate (issue 21 item 7).

    python -m bench.retrain_compare --model old=learned new=RUN/model.pt [--test TEST.h5 ...]
        [--real-items pyramid skull] [--work DIR] [--json OUT.json]
    python -m bench.retrain_compare --merge old.json new.json     # runs of one model each, same sources

Rows per source (error rate = wrong orders / pixels with valid inputs and a reference order; every
row of a source on the same pixels, nothing dropped): Traditional (the prior rounded), old model,
new model, and each model + graph cut (:func:`unwrap.spatial_orders.graphcut_orders` with the
network's log-probabilities as data term, shipped constants).

Sources: the real captures of :mod:`bench.spatial_unwrap` (pyramid v / h: MF 1 -> 16 with its
ladder's reference; SLStudio's skull: MF 1 -> 16, Gray-code reference), and twin / Cycles
dataset files (``--test``: MF (1, f) and MW (f - 1, f) for every f of ``--freqs`` the file holds;
a file's pixels are those ``unwrap.dataset`` counts: valid inputs and a geometric order).
The decision rule for shipping (docs/learned.md) reads this table.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from bench.spatial_unwrap import _pyramid_items, _skull_items, _sigmas
from unwrap.safe_output import write_text


def _dataset_items(path, freqs, methods, max_items=None):
    """Items of a dataset file for each (method, f): MF (1, f) and MW (f - 1, f) where held."""
    import h5py

    from experiments.learned_parity import capture_noise
    from unwrap.dataset import FringeOrderDataset
    from unwrap.dataset_schema import read_attrs

    with h5py.File(path, "r") as h5:
        a = read_attrs(h5)
    have = {float(f) for f in a["frequencies"]}
    widths = a.get("widths") or {}
    items = []
    for o in a["orientations"]:
        width = float(widths[o]) if isinstance(widths, dict) and o in widths else 912.0
        for f in freqs:
            noise = None            # the sensor's noise (an MF pair): read once per (orientation, f), not per method
            for m in methods:
                pair = (1.0, float(f)) if m == "mf" else (float(f) - 1, float(f))
                if not set(pair) <= have:
                    continue
                noise = noise or capture_noise(path, o, (min(have), float(f)))
                ds = FringeOrderDataset(path, method=m, frequencies=pair, orientation=o, crop=None, seed=0)
                n = len(ds) if max_items is None else min(len(ds), max_items)
                for i in range(n):
                    it = ds[i]
                    items.append(dict(
                        name=f"{Path(path).stem} {m.upper()} {pair[0]:g}/{pair[1]:g} {o}", method=m,
                        phase_low=it["phase_low"][0].numpy().astype(np.float64),
                        phase_high=it["phase_high"][0].numpy().astype(np.float64),
                        m_low=it["modulation_low"][0].numpy().astype(np.float64),
                        m_high=it["modulation_high"][0].numpy().astype(np.float64),
                        valid=it["valid"].numpy(), ref=it["order_true"].numpy().astype(np.int64), freqs=pair,
                        width=width, steps=noise["steps"], sigma_I=noise["sigma_I"]))
    return items


def decode(it, models: dict, graph_cut: bool) -> dict:
    """{row: orders} for one item: Traditional, then each model (and + graph cut)."""
    from unwrap.learned.infer import unwrap_learned
    from unwrap.spatial_orders import graphcut_orders
    from unwrap.temporal import decode_pair

    m = it.get("method", "mf")
    _, n, ok = decode_pair(m, it["phase_low"], it["phase_high"], *it["freqs"], it["width"], it["valid"])
    out = {"Traditional": n}
    s_lo, s_hi = _sigmas(it) if graph_cut else (None, None)
    for name, model in models.items():
        r = unwrap_learned(m, it["phase_low"], it["phase_high"], it["m_low"], it["m_high"], ok, it["freqs"],
                           width=it["width"], model=model, on_outside="warn", log_probs=graph_cut)
        out[f"Learned {name}"] = r.order
        if graph_cut:
            g = graphcut_orders(m, it["phase_low"], it["phase_high"], it["freqs"], ok, s_lo, s_hi,
                                width=it["width"], cost=-r.log_probs)
            out[f"Learned {name} + graph cut"] = g.order
    return out, ok


def score(items, models, graph_cut):
    res = {}
    for it in items:
        label = it["name"].split(" #")[0]
        t0 = time.perf_counter()
        out, ok = decode(it, models, graph_cut)
        mask = ok & (it["ref"] >= 0)
        R = res.setdefault(label, {"pixels": 0, "rows": {}})
        R["pixels"] += int(mask.sum())
        for row, k in out.items():
            w = R["rows"].get(row, 0)
            R["rows"][row] = w + int((k != it["ref"])[mask].sum())
        print(f"{it['name']}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    return res


def merge(parts: list) -> tuple[dict, dict]:
    """Results of several runs over the same sources (one model each) -> one result; the
    traditional rows and pixel counts must agree (same pixels)."""
    models, res = {}, {}
    for part in parts:
        models.update(part["models"])
        for label, R in part["results"].items():
            if label not in res:
                res[label] = {"pixels": R["pixels"], "rows": dict(R["rows"])}
                continue
            if R["pixels"] != res[label]["pixels"] or R["rows"]["Traditional"] != res[label]["rows"]["Traditional"]:
                raise SystemExit(f"--merge: {label} differs between the runs (not the same pixels)")
            res[label]["rows"].update(R["rows"])
    return res, models


def table(res, models) -> str:
    names = list(models)
    rows = ["Traditional"] + [f"Learned {n}" for n in names] + [f"Learned {n} + graph cut" for n in names]
    rows = [r for r in rows if any(r in R["rows"] for R in res.values())]
    L = ["| source (pixels) | " + " | ".join(rows) + " | new / old |", "|---|" + "---:|" * (len(rows) + 1)]
    for label, R in res.items():
        p = max(R["pixels"], 1)
        rates = [100 * R["rows"][r] / p for r in rows]
        ratio = (R["rows"][f"Learned {names[1]}"] / max(R["rows"][f"Learned {names[0]}"], 1)) if len(names) > 1 else 1
        L.append(f"| {label} ({R['pixels']:,}) | " + " | ".join(f"{v:.3f}" for v in rates) + f" | {ratio:.2f} |")
    L.append("")
    L.append("(error % of the pixels with a reference; new / old = ratio of the learned rows' wrong pixels)")
    return "\n".join(L)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.retrain_compare", description=__doc__.split("\n")[0])
    ap.add_argument("--model", nargs="*", default=[], metavar="NAME=MODEL",
                    help="models to score, e.g. old=learned new=runs/x/model.pt (learned: the shipped one)")
    ap.add_argument("--merge", nargs="*", default=None, metavar="JSON", help="combine earlier runs' --json files")
    ap.add_argument("--test", nargs="*", default=[], help="dataset files (twin / Cycles) with geometric orders")
    ap.add_argument("--freqs", nargs="*", type=float, default=[48.0, 96.0])
    ap.add_argument("--methods", nargs="*", default=["mf", "mw"], choices=["mf", "mw", "nt"])
    ap.add_argument("--max-items", type=int, default=None, help="at most this many scenes per file and pair")
    ap.add_argument("--real-items", nargs="*", default=["pyramid", "skull"], choices=["pyramid", "skull"])
    ap.add_argument("--no-graph-cut", action="store_true")
    ap.add_argument("--work", default="/tmp/sltwin_bench_spatial", help="cache of exported captures")
    ap.add_argument("--json", default=None)
    ap.add_argument("--quick", action="store_true", help="the shipped model on the pyramid's v orientation, no graph cut")
    a = ap.parse_args(argv)
    if a.merge:
        res, models = merge([json.loads(Path(p).read_text()) for p in a.merge])
        print(table(res, models))
        return 0
    models = dict(m.split("=", 1) for m in a.model)
    if a.quick:
        models = models or {"shipped": "learned"}
        a.real_items, a.test, a.no_graph_cut = [], [], True
    if not models:
        ap.error("give --model NAME=MODEL (one or more) or --merge")
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    items = _pyramid_items(("v",)) if a.quick else []
    if "pyramid" in a.real_items:
        items += _pyramid_items()
    if "skull" in a.real_items:
        items += _skull_items(work)
    for p in a.test:
        items += _dataset_items(p, a.freqs, a.methods, a.max_items)
    res = score(items, models, not a.no_graph_cut)
    print(table(res, models))
    if a.json:
        write_text(Path(a.json), json.dumps({"models": models, "results": res}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
