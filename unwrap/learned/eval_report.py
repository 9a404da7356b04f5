"""``calib eval``: the S5 and S6 layouts with the paper's numbers beside ours, the confidence
curve, real captures, speed; written as Markdown + JSON + figures.

SYNOPSIS

    from unwrap.learned.eval_report import run_evaluation
    from unwrap.learned.evaluate import TestSource
    res = run_evaluation(TestSource(files=["test.h5"]), "out/eval", physics="model.pt",
                         prior_free="pf.pt", mse_only="mse.pt", real=["skull.h5"])
    print(res["markdown"])
"""
from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np

from ..methods import PAIR_METHODS
from .checkpoint import load_model
from .evaluate import DROPS, TestSource, confidence_curve, score, speed_table
from .metrics import ErrorCount
from .paper import TABLE_S5, TABLE_S6

log = logging.getLogger("unwrap.learned")
ROW_PF, ROW_PA, ROW_MSE = "DT-TPU (prior-free)", "DP-TPU (physics-aware)", "MSE"


def _pct(x) -> str:
    return "-" if x is None or x != x else f"{100 * x:.2f}"


def _paper(x) -> str:
    return "-" if x is None else f"{x:.2f}"


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
    from ..dataset import FringeOrderDataset
    import h5py

    from ..dataset_schema import read_attrs
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
        from .data import MethodTagged
        return MethodTagged(self._ds, method)


# ---------------------------------------------------------------- figures
def _figures(out: Path, s5: dict, s6: dict, physics_name: str) -> list[str]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    made = []
    scored = s5["scored"]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for ax, f in zip(axes, sorted({k[1] for k in scored})):
        for m in PAIR_METHODS:
            s = scored.get((m, f))
            if s is None or physics_name not in s.confidence:
                continue
            curve = confidence_curve(s, physics_name, DROPS)
            ax.plot([100 * d for d, _ in curve], [100 * e for _, e in curve], "o-", label=m.upper())
        ax.set(xlabel="pixels dropped, least confident first [%]", ylabel="error rate of kept pixels [%]",
               title=f"confidence, f = {f:g}")
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    fig.savefig(out / "confidence.png", dpi=110)
    plt.close(fig)
    made.append("confidence.png")
    for f in sorted({k[1] for k in scored}):
        s = scored.get(("mf", f))
        ex = s.checks.get("example") if s is not None else None
        if ex is None:
            continue
        made.append(error_map_figure(out / f"error_maps_mf{int(f)}.png", ex, physics_name, f"MF, f = {f:g}"))
    if s6:
        fig, ax = plt.subplots(figsize=(6, 3.8))
        for m in PAIR_METHODS:
            fs = [f for f in sorted(s6) if m in s6[f]]
            if not fs:
                continue
            line, = ax.plot(fs, [100 * s6[f][m]["MSE + FL"] for f in fs], "o-", label=f"{m.upper()} MSE + FL")
            if all(s6[f][m]["MSE"] is not None for f in fs):
                ax.plot(fs, [100 * s6[f][m]["MSE"] for f in fs], "s--", color=line.get_color(), label=f"{m.upper()} MSE")
            ax.plot(fs, [100 * s6[f][m]["traditional"] for f in fs], ":", color=line.get_color(), alpha=0.6)
        ax.set(xlabel="fringe frequency f (trained at 48)", ylabel="error rate [%]", title="S6 layout (dotted: traditional)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out / "s6.png", dpi=110)
        plt.close(fig)
        made.append("s6.png")
    return made


def error_map_figure(path: Path, ex: dict, model_name: str, title: str) -> str:
    """Wrong-order maps of the traditional method and the model on one frame, plus the confidence."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    true, valid = ex["true"], ex["valid"] & (ex["true"] >= 0)
    panels = [("traditional", ex["traditional"]), (model_name, ex[model_name])]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for ax, (name, k) in zip(axes, panels):
        img = np.where(valid, (k != true).astype(float), np.nan)
        ax.imshow(img, cmap="Reds", vmin=0, vmax=1, interpolation="nearest")
        ax.set_title(f"{name}: {100 * np.nanmean(img):.2f} % wrong")
        ax.axis("off")
    c = np.where(valid, ex[model_name + " confidence"], np.nan)
    im = axes[2].imshow(c, cmap="viridis", vmin=0, vmax=1, interpolation="nearest")
    axes[2].set_title("confidence")
    axes[2].axis("off")
    fig.colorbar(im, ax=axes[2], fraction=0.04)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path.name


# ---------------------------------------------------------------- markdown
def markdown(res: dict) -> str:
    L = [f"# Learned unwrapping: evaluation ({res['source']})", "",
         "Error rate = wrong fringe orders / pixels with valid inputs and a true order (every row on the "
         "same pixels). Pairs: MF (1, f), MW and NT (f - 1, f). Paper: Liu et al., supplementary "
         "tables S5 / S6.", ""]
    s5 = res.get("s5") or {}
    if s5:
        L += ["## S5 layout: traditional vs prior-free vs physics-aware [%]", "",
              "| f | method | " + " | ".join(f"{m.upper()} ours | {m.upper()} paper" for m in PAIR_METHODS) + " |",
              "|---|---|" + "---:|---:|" * len(PAIR_METHODS)]
        for f, rows in s5.items():
            tag = "seen" if int(f) == 48 else "unseen"
            for row, per in rows.items():
                cells = []
                for m in PAIR_METHODS:
                    c = per.get(m, {})
                    cells += [_pct(c.get("ours")), _paper(c.get("paper"))]
                L.append(f"| {f} ({tag}) | {row} | " + " | ".join(cells) + " |")
        L += ["", "UNet-TPU (prior-free, trained on real captures) is absent: no real training set of "
              "reasonable size with reference orders exists (of the real captures in ../shared/data only "
              "SLStudio's skull has a reference order, from its Gray-code scan: one capture, too few to train on and needed as the real test; the SLStudio "
              "calibration poses have no reference, kamino and SLMaster no unit-frequency MF pair).", ""]
    s6 = res.get("s6") or {}
    if s6:
        L += ["## S6 layout: MSE vs MSE + Fourier loss [%]", "",
              "| f | " + " | ".join(f"{m.upper()} MSE | {m.upper()} MSE+FL | {m.upper()} paper" for m in PAIR_METHODS)
              + " | MF traditional | MF prior-free |", "|---|" + "---:|---:|---:|" * len(PAIR_METHODS) + "---:|---:|"]
        for f, per in s6.items():
            cells = []
            for m in PAIR_METHODS:
                c = per.get(m, {})
                p = c.get("paper")
                cells += [_pct(c.get("MSE")), _pct(c.get("MSE + FL")), "-" if p is None else f"{p[0]:.2f} / {p[1]:.2f}"]
            mf = per.get("mf", {})
            L.append(f"| {f} | " + " | ".join(cells) + f" | {_pct(mf.get('traditional'))} | {_pct(mf.get('prior_free'))} |")
        L.append("")
    conf = res.get("confidence") or {}
    if conf:
        L += ["## Confidence: error rate of the kept pixels vs the fraction dropped (physics-aware) [%]", "",
              "| method, f | " + " | ".join(f"drop {100 * d:g} %" for d in DROPS) + " |",
              "|---|" + "---:|" * len(DROPS)]
        for key, curve in conf.items():
            L.append(f"| {key} | " + " | ".join(_pct(e) for _, e in curve) + " |")
        L.append("")
    real = res.get("real") or []
    if real:
        L += ["## Real captures (reference orders from the export) [%]", "",
              "| capture | pair | samples | pixels | traditional | filtered | learned | model check |",
              "|---|---|---:|---:|---:|---:|---:|---|"]
        for r in real:
            if "note" in r:
                L.append(f"| {r['capture']} | {r['note']} | | | | | | |")
                continue
            filt = next((v for k, v in r.items() if k.startswith("Filtered")), None)
            chk = r.get("check") or {}
            L.append(f"| {r['capture']} | {r['pair'][0]:g}, {r['pair'][1]:g} | {r['samples']} | {r['pixels']} | "
                     f"{_pct(r['Traditional'])} | {_pct(filt)} | {_pct(r[ROW_PA])} | "
                     f"ratio x{chk.get('ratio_factor', float('nan')):.2f} of training, period "
                     f"{chk.get('period_px', float('nan')):.0f} px: {chk.get('status', '')} |")
        L.append("")
    sp = res.get("speed")
    if sp:
        L += [f"## Speed (one orientation, {sp['size']}, {sp['device']}, {sp['threads']} threads, minimum of repeats"
              f"{'; shared machine' if sp.get('shared') else ''})", "",
              "| step | ms |", "|---|---:|"]
        for k in ("traditional_from_frames_ms", "traditional_from_phases_ms", "filtered_ms", "network_forward_ms",
                  "learned_total_ms"):
            L.append(f"| {k[:-3].replace('_', ' ')} | {sp[k]:.1f} |")
        for name, v in (res.get("training") or {}).items():
            L.append(f"| training {name}: samples/s | {v:.2f} |")
        L.append("")
    return "\n".join(L)


def run_evaluation(source: TestSource, out_dir, *, physics, prior_free=None, mse_only=None, real=(),
                   s5_frequencies=(48, 96), s6_frequencies=(16, 32, 48, 64, 80, 96), methods=PAIR_METHODS,
                   filtered_window: int = 15, speed: bool = True, training_runs: dict | None = None,
                   shared_machine: bool = True) -> dict:
    """Everything ``calib eval`` prints and saves (module docstring); returns the result dict with
    ``markdown`` and the written file names."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    models = {}
    if prior_free is not None:
        models[ROW_PF] = load_model(prior_free)
    models[ROW_PA] = load_model(physics)
    if mse_only is not None:
        models[ROW_MSE] = load_model(mse_only)
    cache = _Cache(source, models, filtered_window)
    res: dict = {"source": source.label or (", ".join(map(str, source.files)) or "synthetic")}
    s5 = table_s5(cache, s5_frequencies, methods)
    res["s5"] = s5["table"]
    res["confidence"] = {f"{m.upper()}, {f:g}": confidence_curve(s, ROW_PA) for (m, f), s in s5["scored"].items()
                         if s is not None}
    res["s6"] = table_s6(cache, s6_frequencies, methods) if s6_frequencies else {}
    res["checks"] = {f"{m} {f:g}": s.checks.get(ROW_PA) for (m, f), s in s5["scored"].items() if s is not None}
    if real:
        rows = real_table(real, models[ROW_PA], window=filtered_window)
        for r in rows:
            s = r.pop("_scored", None)
            if s is not None and "example" in s.checks:
                r["figure"] = error_map_figure(out / f"real_{r['capture'].replace(' ', '_')}.png", s.checks["example"],
                                               ROW_PA, f"real capture {r['capture']}")
        res["real"] = rows
    if speed:
        res["speed"] = {**speed_table(models[ROW_PA]), "shared": shared_machine}
    if training_runs:
        res["training"] = {}
        for name, run in training_runs.items():
            p = Path(run) / "metrics.json"
            if p.is_file():
                res["training"][name] = json.loads(p.read_text())["train_samples_per_s"]
    res["figures"] = _figures(out, s5, res["s6"], ROW_PA)
    md = markdown(res)
    (out / "eval.md").write_text(md)
    (out / "eval.json").write_text(json.dumps(res, indent=1, default=_json_default))
    res["markdown"] = md
    return res


def _json_default(o):
    if isinstance(o, ErrorCount):
        return {"wrong": o.wrong, "counted": o.counted}
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    return str(o)
