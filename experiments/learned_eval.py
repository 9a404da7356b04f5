"""``calib eval``'s experiment: the S5 and S6 tables with the paper's numbers beside ours, the
confidence curve, real captures, speed (laid out as Markdown + JSON + figures by
:mod:`reports.learned_eval`).

SYNOPSIS

    from experiments.learned_eval import evaluate_models
    from experiments.learned_evaluation import TestSource
    from reports.learned_eval import write_evaluation
    res = evaluate_models(TestSource(files=["test.h5"]), physics="model.pt", prior_free="pf.pt",
                          mse_only="mse.pt", real=["skull.h5"])
    print(write_evaluation(res, "out/eval")["markdown"])
"""
from __future__ import annotations

import json
import logging
import time
from pathlib import Path

from twin_mapping.paper_tables import TABLE_S5, TABLE_S6
from unwrap.learned.checkpoint import load_model
from unwrap.learned.errors import ModelError
from unwrap.methods import PAIR_METHODS

from .learned_evaluation import DROPS, TestSource, confidence_curve, score, speed_table

log = logging.getLogger("experiments")
ROW_PF, ROW_PA, ROW_MSE = "DT-TPU (prior-free)", "DP-TPU (physics-aware)", "MSE"


class _Cache:
    """One score() per (method, f) with every model, shared by the S5 and S6 tables."""

    def __init__(self, source, models: dict, filtered_window):
        self.source, self.models, self.window, self.done = source, models, filtered_window, {}

    def get(self, method, f):
        key = (method, float(f))
        if key not in self.done:
            t0 = time.perf_counter()
            self.done[key] = score(self.source, method, f, self.models, filtered_window=self.window,
                                   example=(method == "mf"))
            log.info("scored %s f=%g in %.0f s", method, f, time.perf_counter() - t0)
        return self.done[key]


def table_s5(cache: _Cache, frequencies=(48, 96), methods=PAIR_METHODS) -> dict:
    """{"table": {f: {row: {method: {"ours", "paper", "pixels"}}}}, "scored": {(method, f): Scored}}."""
    out, scored = {}, {}
    names = {"Traditional": "Traditional", ROW_PF: "DT-TPU", ROW_PA: "DP-TPU"}
    for f in frequencies:
        rows: dict = {}
        for m in methods:
            s = cache.get(m, f)
            scored[(m, f)] = s
            if s is None:
                continue
            paper = TABLE_S5.get(int(f), {})
            for row in [r for r in s.counts if r != ROW_MSE]:
                p = paper.get(names.get(row, ""))
                rows.setdefault(row, {})[m] = {"ours": s.counts[row].rate, "pixels": s.counts[row].counted,
                                               "paper": None if p is None else p[PAIR_METHODS.index(m)]}
        out[int(f)] = rows
    return {"table": out, "scored": scored}


def table_s6(cache: _Cache, frequencies=(16, 32, 48, 64, 80, 96), methods=PAIR_METHODS) -> dict:
    """{f: {method: {"MSE": rate or None, "MSE + FL": rate, "traditional": rate, "paper": (mse, msefl)}}}."""
    out = {}
    for f in frequencies:
        row = {}
        for m in methods:
            s = cache.get(m, f)
            if s is None:
                continue
            p = TABLE_S6.get(int(f), {}).get(m.upper())
            row[m] = {"MSE": s.counts[ROW_MSE].rate if ROW_MSE in s.counts else None,
                      "MSE + FL": s.counts[ROW_PA].rate, "traditional": s.counts["Traditional"].rate,
                      "prior_free": s.counts[ROW_PF].rate if ROW_PF in s.counts else None,
                      "paper": p, "pixels": s.counts[ROW_PA].counted}
        out[int(f)] = row
    return out


def real_table(files, physics, *, window: int = 15) -> list[dict]:
    """Per real capture file and orientation with a reference: traditional, filtered and learned error
    rates (MF with the file's unit frequency and its highest one)."""
    from unwrap.dataset import FringeOrderDataset
    import h5py

    from unwrap.dataset_schema import read_attrs
    rows = []
    for path in files:
        with h5py.File(path, "r") as h5:
            a = read_attrs(h5)
        freqs = sorted(float(f) for f in a["frequencies"])
        if not freqs or freqs[0] > 1 + 1e-9 or len(freqs) < 2:
            rows.append({"capture": Path(path).stem, "note": f"no MF pair (frequencies {freqs}): not scored"})
            continue
        pair = (freqs[0], freqs[-1])
        for o in a["orientations"]:
            ds = FringeOrderDataset(path, method="mf", frequencies=pair, orientation=o, crop=None, seed=0)
            src = _OneFile(ds)
            s = score(src, "mf", pair[1], {ROW_PA: physics}, filtered_window=window, example=True)
            if s is None or s.counts["Traditional"].counted == 0:
                rows.append({"capture": f"{Path(path).stem} {o}", "note": "no reference order"})
                continue
            rows.append({"capture": f"{Path(path).stem} {o}", "pair": list(pair), "samples": s.items,
                         "pixels": s.counts["Traditional"].counted,
                         **{k: v.rate for k, v in s.counts.items()}, "check": s.checks.get(ROW_PA),
                         "_scored": s})
    return rows


class _OneFile(TestSource):
    """A TestSource over one already-open reader dataset (real captures: pair from the file)."""

    def __init__(self, ds):
        super().__init__(orientations=(ds.orientation,))
        self._ds = ds

    def dataset(self, method, f, orientation):
        from unwrap.learned.data import MethodTagged
        return MethodTagged(self._ds, method)


def evaluate_models(source: TestSource, *, physics, prior_free=None, mse_only=None, real=(),
                    s5_frequencies=(48, 96), s6_frequencies=(16, 32, 48, 64, 80, 96), methods=PAIR_METHODS,
                    filtered_window: int = 15, speed: bool = True, training_runs: dict | None = None,
                    shared_machine: bool = True, cycles=()) -> dict:
    """Everything ``calib eval`` reports (module docstring), computed: the S5 and S6 tables with the
    paper's numbers, confidence curves, per-capture rows, speed and training rates, and under
    ``"plots"`` what the figures draw (confidence curves per frequency and method, example frames);
    ``reports.learned_eval.write_evaluation`` lays it out."""
    models = {}
    if prior_free is not None:
        models[ROW_PF] = load_model(prior_free)
    models[ROW_PA] = load_model(physics)
    if mse_only is not None:
        models[ROW_MSE] = load_model(mse_only)
    cache = _Cache(source, models, filtered_window)
    res: dict = {"source": source.label or (", ".join(map(str, source.files)) or "synthetic"), "model": ROW_PA}
    s5 = table_s5(cache, s5_frequencies, methods)
    missing = [f"{m} {f:g}" for (m, f), s in s5["scored"].items() if s is None]
    if missing and len(missing) == len(s5["scored"]):   # an empty table is no result
        raise ModelError(f"{res['source']}: no cell of table S5 can be scored: the test data hold none of "
                         f"(method, frequency) {missing} (the pairs 1 -> f of each method, both orientations "
                         "looked for); give --s5 frequencies the data were exported with")
    if missing:
        log.warning("table S5: %s not in the test data: those cells stay empty", ", ".join(missing))
    res["s5"] = s5["table"]
    res["confidence"] = {f"{m.upper()}, {f:g}": confidence_curve(s, ROW_PA) for (m, f), s in s5["scored"].items()
                         if s is not None}
    res["s6"] = table_s6(cache, s6_frequencies, methods) if s6_frequencies else {}
    res["checks"] = {f"{m} {f:g}": s.checks.get(ROW_PA) for (m, f), s in s5["scored"].items() if s is not None}
    if cycles:  # the Cycles test set (experiments.cycles_testset): MF only, v fringes, its own section
        cyc = _Cache(TestSource(files=list(cycles), orientations=("v",), label="Cycles set"), models, filtered_window)
        res["cycles"] = table_s5(cyc, s5_frequencies, ("mf",))["table"]
    if real:
        rows = real_table(real, models[ROW_PA], window=filtered_window)
        for r in rows:
            s = r.pop("_scored", None)
            if s is not None and "example" in s.checks:
                r["example"] = s.checks["example"]
        res["real"] = rows
    if speed:
        # the model as deployed (a checkpoint file: the CPU fast path; a (net, ck) pair runs plain)
        res["speed"] = {**speed_table(physics), "shared": shared_machine}
    if training_runs:
        res["training"] = {}
        for name, run in training_runs.items():
            p = Path(run) / "metrics.json"
            if p.is_file():
                res["training"][name] = json.loads(p.read_text())["train_samples_per_s"]
    res["plots"] = _plot_data(s5["scored"], ROW_PA)
    return res


def _plot_data(scored: dict, physics_name: str) -> dict:
    """{"confidence": {f: {method: curve}}, "examples": {f: example frame of MF}} for the figures."""
    freqs = sorted({k[1] for k in scored})
    curves = {f: {m: confidence_curve(scored[(m, f)], physics_name, DROPS) for m in PAIR_METHODS
                  if scored.get((m, f)) is not None and physics_name in scored[(m, f)].confidence} for f in freqs}
    examples = {f: scored[("mf", f)].checks.get("example") for f in freqs if scored.get(("mf", f)) is not None}
    return {"confidence": curves, "examples": {f: ex for f, ex in examples.items() if ex is not None}}
