"""``calib eval``'s layout: the S5 and S6 tables with the paper's numbers beside ours, the
confidence figure, error maps, real captures and speed, from the result of
:func:`experiments.learned_eval.evaluate_models`; written as Markdown + JSON + figures."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from experiments.learned_eval import ROW_PA
from experiments.learned_evaluation import DROPS
from unwrap.learned.metrics import ErrorCount
from unwrap.methods import PAIR_METHODS
from unwrap.safe_output import save_figure, write_text


def _pct(x) -> str:
    return "-" if x is None or x != x else f"{100 * x:.2f}"


def _paper(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def _figures(out: Path, plots: dict, s6: dict, physics_name: str) -> list[str]:
    """confidence.png, error_maps_mf<f>.png, s6.png from the plotted data; their file names."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    made = []
    curves = plots["confidence"]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for ax, f in zip(axes, sorted(curves)):
        for m, curve in curves[f].items():
            ax.plot([100 * d for d, _ in curve], [100 * e for _, e in curve], "o-", label=m.upper())
        ax.set(xlabel="pixels dropped, least confident first [%]", ylabel="error rate of kept pixels [%]",
               title=f"confidence, f = {f:g}")
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    save_figure(fig, out / "confidence.png", dpi=110)
    plt.close(fig)
    made.append("confidence.png")
    for f, ex in sorted(plots["examples"].items()):
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
        save_figure(fig, out / "s6.png", dpi=110)
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
    save_figure(fig, path, dpi=100)
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
    L += _cycles_section(res.get("cycles") or {})
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


def _cycles_section(cyc: dict) -> list:
    """The Cycles test set's rows (experiments.learned_eval ``res["cycles"]``), or nothing."""
    if not cyc:
        return []
    L = ["## Cycles set: held-out meshes rendered by Blender Cycles, bias-dominated (MF, v) [%]", "",
         "| f | row | error % | traditional / row | pixels |", "|---|---|---:|---:|---:|"]
    for f, rows in cyc.items():
        t = (rows.get("Traditional") or {}).get("mf", {}).get("ours")
        for row, per in rows.items():
            r = per.get("mf", {}).get("ours")
            L.append(f"| {f} | {row} | {_pct(r)} | {'-' if not r or t is None else f'{t / r:.2f}x'} | "
                     f"{per.get('mf', {}).get('pixels', '')} |")
    return L + [""]


def write_evaluation(res: dict, out_dir) -> dict:
    """Figures, ``eval.md`` and ``eval.json`` of an evaluation result in ``out_dir``; returns the
    result with ``markdown``, ``figures`` and each real row's ``figure`` (the plotted arrays are
    not written to the JSON)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    res = dict(res)
    plots = res.pop("plots", {"confidence": {}, "examples": {}})
    rows = []
    for r in res.get("real", []):
        r = dict(r)
        ex = r.pop("example", None)
        if ex is not None:
            r["figure"] = error_map_figure(out / f"real_{r['capture'].replace(' ', '_')}.png", ex, res["model"],
                                           f"real capture {r['capture']}")
        rows.append(r)
    if "real" in res:
        res["real"] = rows
    res["figures"] = _figures(out, plots, res["s6"], res["model"])
    md = markdown(res)
    write_text(out / "eval.md", md)
    write_text(out / "eval.json", json.dumps(res, indent=1, default=_json_default))
    res["markdown"] = md
    return res


def _json_default(o):
    if isinstance(o, ErrorCount):
        return {"wrong": o.wrong, "counted": o.counted}
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    return str(o)
