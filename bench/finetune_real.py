"""Adapting the shipped fringe-order model to a scanner: fine-tune on labelled real captures, test
on a held-out one, beside the traditional decode and the shipped model (docs/learned.md,
"Adapting to your scanner").

Run: ``python -m bench.finetune_real [--steps N] [--work DIR] [--only pyramid|skull]`` (``--quick``:
20 steps, the first case only: checks that it runs, numbers not for quoting)

Cases (each: fine-tune on the TRAIN file(s), score MF (1, 16) on the TEST file; the test file is
the run's validation set, scored once at the last step, so nothing is selected on it):

- pyramid (../shared/data/thomriiii-pyramid-mf-1-4-16, MF 1/4/16, 8 steps, noisy): each
  orientation is a capture (different fringes, same scene and camera pixels); reference = the
  1 -> 4 -> 16 ladder (``--reference ladder``), labelled pair 1 -> 16. v -> h and h -> v, and
  the top half of v -> h (half the data).
- skull (../shared/data/slstudio-ps2x3-calib, MF 1/16, 3 steps): one capture only, so its two
  disjoint halves (``--region top`` / ``bottom``; the skull fills the right half of the frame, so
  left / right would leave one half almost empty; the other half is unlit in each file);
  reference = the Gray-code point cloud projected with the calibration (docs/dataset.md). top -> bottom and
  bottom -> top.

Error rate = wrong orders / valid pixels with a reference (experiments.learned_evaluation.score). The
cost column is the fine-tuning run's steps and CPU seconds (train.csv, whole process).
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
PYRAMID = SHARED / "thomriiii-pyramid-mf-1-4-16"
SKULL = SHARED / "slstudio-ps2x3-calib"

PYRAMID_TOML = """# thomriiii pyramid, frames linked in the DESIGN.md layout (bench.finetune_real)
[capture]
preset = "design"
method = "mf"
[pattern]
steps = 8
frequencies = [1, 4, 16]
shift_sign = -1          # their frames are A + B cos(phi + 2 pi k / 8)
[projector]
size = [1024, 768]
"""


def pyramid_capture(work: Path) -> Path:
    """A DESIGN.md capture folder of symlinks to the pyramid's frames (the data stay in place)."""
    d = work / "pyramid_capture"
    d.mkdir(parents=True, exist_ok=True)
    for o, name in (("v", "vertical"), ("h", "horizontal")):
        for f in (1, 4, 16):
            for n in range(8):
                link = d / f"{o}_f{f:03d}_n{n:02d}.png"
                if not link.exists():
                    link.symlink_to(PYRAMID / "structured" / name / f"f_{f:03d}" / f"step_{n:03d}.png")
    (d / "capture.toml").write_text(PYRAMID_TOML)
    return d


def export_files(work: Path, only=None) -> dict:
    """{name: .h5} of the labelled captures (skipped when the shared data are absent)."""
    from synth.export.capture import export_capture

    files = {}
    if PYRAMID.exists() and only in (None, "pyramid"):
        cap = pyramid_capture(work)
        for o in ("v", "h"):
            out = work / f"pyramid_{o}.h5"
            s = export_capture(cap, out, reference="ladder", orientations=[o])
            files[f"pyramid {o}"] = (out, s["captures"][0]["orientations"][o])
        out = work / "pyramid_v_top.h5"     # half a capture: how much data the adaptation needs
        s = export_capture(cap, out, reference="ladder", orientations=["v"], region="top")
        files["pyramid v top half"] = (out, s["captures"][0]["orientations"]["v"])
    if SKULL.exists() and only in (None, "skull"):
        for half in ("top", "bottom"):
            out = work / f"skull_{half}.h5"
            s = export_capture(SKULL / "skull_2x3", out, reference="cloud", region=half,
                               reference_cloud=SKULL / "skull_reference" / "pointCloud_from_skull_gray.mat",
                               reference_system=SKULL / "calibration" / "calibration.xml")
            files[f"skull {half}"] = (out, s["captures"][0]["orientations"]["v"])
    return files


def finetune(train_files, test_file, run_dir: Path, steps: int) -> dict:
    from unwrap.learned.train import train

    cfg = Path(__file__).resolve().parents[1] / "unwrap" / "learned" / "data" / "finetune_real.toml"
    train(cfg, [f"data.train={json.dumps([str(p) for p in train_files])}",
                f"data.val_files={json.dumps([str(test_file)])}", f"optim.steps={steps}"], run_dir, progress=False)
    return json.loads((run_dir / "metrics.json").read_text())


def score_file(path, models: dict) -> dict:
    import h5py

    from unwrap.dataset_schema import read_attrs
    from experiments.learned_evaluation import TestSource, score

    with h5py.File(path, "r") as h5:
        orients = tuple(read_attrs(h5)["orientations"])
    s = score(TestSource(files=[str(path)], orientations=orients), "mf", 16, models, filtered_window=None)
    return {name: (c.rate, c.counted) for name, c in s.counts.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=300, help="fine-tuning steps per case (default 300)")
    ap.add_argument("--work", help="folder for the exports and runs (default: a temporary one)")
    ap.add_argument("--only", choices=("pyramid", "skull"))
    ap.add_argument("--quick", action="store_true", help="20 steps, first case only")
    args = ap.parse_args(argv)
    if args.quick:
        args.steps = 20
    from unwrap.learned.infer import shipped_model_path

    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="finetune_real_"))
    work.mkdir(parents=True, exist_ok=True)
    files = export_files(work, args.only)
    if not files:
        print(f"no real captures under {SHARED}: nothing to measure")
        return 0
    for name, (_, stats) in files.items():
        print(f"{name}: reference {json.dumps(stats)}")
    cases = [(a, b) for a, b in (("pyramid v", "pyramid h"), ("pyramid h", "pyramid v"),
                                 ("pyramid v top half", "pyramid h"),
                                 ("skull top", "skull bottom"), ("skull bottom", "skull top"))
             if a in files and b in files]
    cases = cases[:1] if args.quick else cases
    rows = []
    for train_name, test_name in cases:
        run = work / f"run_{train_name.replace(' ', '_')}"
        m = finetune([files[train_name][0]], files[test_name][0], run, args.steps)
        r = score_file(files[test_name][0], {"shipped": str(shipped_model_path()), "fine-tuned": str(run / "model.pt")})
        rows.append((train_name, test_name, r, m))
        print(f"{train_name} -> {test_name}: " + ", ".join(f"{k} {100 * v[0]:.3f} %" for k, v in r.items())
              + f"; {m['step']} steps, {m['cpu_s_total']:.0f} CPU s", flush=True)
    print("\n| fine-tuned on | held-out test | pixels | traditional | shipped | fine-tuned | steps | CPU s |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for a, b, r, m in rows:
        cells = " | ".join(f"{100 * r[k][0]:.3f} % ({round(r[k][0] * r[k][1]):,})"
                           for k in ("Traditional", "shipped", "fine-tuned"))
        print(f"| {a} | {b} | {r['Traditional'][1]:,} | {cells} | {m['step']} | {m['cpu_s_total']:.0f} |")
    print(f"\n(exports and runs in {work})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
