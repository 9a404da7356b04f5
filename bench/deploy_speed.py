"""What accuracy costs in time at deployment (issue 22): every row of the issue's table beside its
anchor, measured in the same run.

    python -m bench.deploy_speed [--repeats 3] [--views 100] [--baseline DIR] [--quick]

Rows (times are minima over ``repeats``; the machine is shared, so read the ratios to the anchors):

- ``calib run --observations`` on the paper's 9 real views (../shared/data/dp-tpu) and on a
  simulated ``--views``-view joint session (bench.ba_scale's): wall time of the whole command
  (a fresh process: start-up, imports, figures included), its peak resident memory, and the solve
  time it reports, and its own stage profile (``calibration.json`` ``run`` of its fastest run; ``bench.calib_speed``
  has the calib rows alone, with more repeats); anchor: mrcal's ``optimize`` on the same number of
  simulated views (single camera, bench.ba_scale's comparison) and our solve in the same process.
- the learned path on one 640 x 480 orientation, MF (1, 48), 12 steps: input features, network
  forward (torch under inference mode, and onnxruntime on the exported model), the whole path
  (traditional prior + features + network + decode) on each runtime and without the forward (its
  logits stored: robust to the forward's noise), and the filtered 15 x 15 baseline; anchor: the traditional decode from the frames and from the wrapped phases.
- ``calib unwrap --model`` on a 900 x 700 capture (:func:`write_capture`; both orientations,
  1/8/48 periods, 12 steps, previews written): wall time and peak memory of the command with the
  shipped torch model and with its ONNX export; anchor: the traditional ``calib unwrap`` on it.
- a batch of captures (``calib unwrap FOLDER``): captures/s, learned (ONNX) and traditional.

``--baseline DIR``: an older checkout (``git archive REV | tar -x -C DIR``) run on the same inputs
in the same run for the command-line rows and the learned rows its code has (its
``unwrap.learned.evaluate.speed_table``, its module before the floor plan): the before / after columns.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DP_TPU = ROOT.parent / "shared" / "data" / "dp-tpu"
# peak memory from /proc/self/status VmHWM: ru_maxrss would carry the parent's peak across fork + exec
_RUNNER = ("import re, sys\nfrom sltwin.cli import main\nrc = main(sys.argv[1:])\n"
           "hwm = re.search(r'VmHWM:\\s+(\\d+)', open('/proc/self/status').read())\n"
           "sys.stderr.write('\\nPEAK_KB %s\\n' % (hwm.group(1) if hwm else 'nan'))\n"
           "sys.exit(rc)\n")


# -- the synthetic capture: a tilted plane with a spherical bump and a shadow, 8-bit frames with
# sensor noise, vertical and horizontal fringes at 1, 8 and 48 periods (also used by the tests)

TOML = """[pattern]
steps = [{steps}, {steps}, {steps}]
frequencies = [1, 8, 48]

[camera]
size = [{W}, {H}]

[projector]
size = [912, 1140]
"""


def write_capture(root, size=(900, 700), seed: int = 0, steps: int = 12, noise_grey: float = 2.0) -> Path:
    """Write a capture in the DESIGN.md layout into ``root`` (created) and return it. ``size``:
    camera (W, H) px."""
    import cv2
    import numpy as np

    from unwrap.patterns import absolute_phase, fringe_intensity

    W, H = (int(s) for s in size)
    root = Path(root)
    pose = root / "pose_00"
    pose.mkdir(parents=True, exist_ok=True)
    (root / "capture.toml").write_text(TOML.format(steps=steps, W=W, H=H))
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    r2 = ((x - 0.55 * W) ** 2 + (y - 0.45 * H) ** 2) / (0.25 * min(W, H)) ** 2
    bump = np.where(r2 < 1, np.sqrt(np.clip(1 - r2, 0, 1)), 0.0)             # a sphere's cap: depth
    shadow = (x > 0.55 * W + 0.25 * min(W, H)) & (x < 0.55 * W + 0.32 * min(W, H)) & (np.abs(y - 0.45 * H) < 0.2 * H)
    albedo = np.where(shadow, 0.03, 0.75 + 0.2 * np.sin(x / 37.0) * np.cos(y / 53.0))
    coords = {"v": (20.0 + 870.0 * x / W + 0.05 * y + 25.0 * bump, 912),
              "h": (30.0 + 1080.0 * y / H + 0.04 * x - 30.0 * bump, 1140)}
    for o, (c, extent) in coords.items():
        for f in (1, 8, 48):
            for n in range(steps):
                I = 255 * albedo * fringe_intensity(absolute_phase(c, f, extent), n, steps, 0.5, 0.4)
                I = np.clip(np.rint(I + rng.normal(0, noise_grey, I.shape)), 0, 255).astype(np.uint8)
                cv2.imwrite(str(pose / f"{o}_f{f:03d}_n{n:02d}.png"), I)
    return root


def command_env(root: Path) -> dict:
    """The environment a timed ``calib`` process runs in: this one, ``root`` first on the path, and
    Python's default bytecode cache. A ``PYTHONDONTWRITEBYTECODE`` set here (this project's shared
    machine sets it) would make every fresh process compile the package's modules from source
    again, ~0.2 s a command that an installed toolkit never pays; the first run of a checkout
    writes its ``__pycache__`` (ignored by git) and the minimum over repeats is the cached one."""
    env = dict(os.environ, PYTHONPATH=str(root))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def bytecode_note() -> str:
    """One line for a table's header: how the timed processes treat bytecode (:func:`command_env`)."""
    return ("fresh processes with Python's default bytecode cache"
            + (" (PYTHONDONTWRITEBYTECODE, set here, is dropped for them)" if os.environ.get("PYTHONDONTWRITEBYTECODE") else ""))


def run_cli(args, root: Path, repeats: int) -> dict:
    """Wall seconds (min over repeats) and peak MB (max) of ``calib ARGS`` in a fresh process with
    ``root`` first on the path, with Python's default bytecode cache (:func:`command_env`)."""
    env = command_env(root)
    walls, peaks, err = [], [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        p = subprocess.run([sys.executable, "-c", _RUNNER, *map(str, args)], capture_output=True, text=True,
                           env=env, cwd=root, timeout=3600)
        walls.append(time.perf_counter() - t0)
        kb = [float(line.split()[1]) for line in p.stderr.splitlines() if line.startswith("PEAK_KB")]
        peaks.append(kb[-1] / 1024 if kb else float("nan"))
        if p.returncode != 0:
            err = (p.stderr.strip().splitlines() or [f"exit {p.returncode}"])[-1]
    return {"wall_s": min(walls), "peak_mb": max(peaks), "error": err}


def measure(argv, root: Path, out: Path, repeats: int) -> dict:
    """``calib ARGV -o OUT``, ``repeats`` fresh processes: walls (each run), peak MB (max), error, and
    the stage profile and solve time of the fastest run (``OUT/calibration.json``: one run's wall and
    stages belong together; None for a command that writes none)."""
    walls, peak, stages, solve, err = [], float("nan"), None, None, None
    for _ in range(repeats):
        (out / "calibration.json").unlink(missing_ok=True)     # a failed run must not read the last one's
        r = run_cli([*argv, "-o", out], root, 1)
        err = err or r["error"]
        peak = r["peak_mb"] if peak != peak else max(peak, r["peak_mb"])
        if (out / "calibration.json").is_file() and (not walls or r["wall_s"] < min(walls)):
            cal = json.loads((out / "calibration.json").read_text())
            stages, solve = (cal.get("run") or {}).get("stages_s"), cal["timings_s"].get("solve_s")
        walls.append(r["wall_s"])
    return {"walls": walls, "peak_mb": peak, "stages": stages, "solve_s": solve, "error": err}


def _best(fn, repeats: int) -> float:
    fn()
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best * 1e3


def learned_rows(onnx_path: Path, repeats: int) -> dict:
    """Milliseconds of the learned path's parts on one 640 x 480 orientation (module docstring)."""
    from unwrap.fused_mf import mf_unwrap_stacks
    from unwrap.learned import fast_features as FF
    from unwrap.learned.baselines import filtered_order
    from experiments.learned_evaluation import speed_scene
    from unwrap.learned.infer import unwrap_learned
    from unwrap.learned.runtime import load_predictor
    from unwrap.temporal import decode_pair as traditional
    from unwrap.temporal import mf_unwrap

    stacks, phi, mods, valid = speed_scene((480, 640))
    torch_pred, ort_pred = load_predictor("learned"), load_predictor(onnx_path)
    prior, trad, ok = traditional("mf", phi[0], phi[1], 1.0, 48.0, 912.0, valid)
    # each forward's input in the layout its path builds (torch on the CPU: channels-last, (H, W, C) memory)
    lay = {"layout": getattr(torch_pred, "input_layout", "nchw"), "multiple": getattr(torch_pred, "multiple", 1)}
    x, _ = FF.make_inputs("physics", "mf", prior, phi[0], phi[1], mods[0], mods[1], trad, ok, (1, 48))
    xt, _ = FF.make_inputs("physics", "mf", prior, phi[0], phi[1], mods[0], mods[1], trad, ok, (1, 48), **lay)
    import torch

    out = {"threads_torch": torch.get_num_threads(), "providers_ort": ",".join(ort_pred.providers),
           "layout_torch": lay["layout"]}
    out["traditional_from_frames_ms"] = _best(lambda: mf_unwrap_stacks(stacks, (1, 48), width=912), repeats)
    out["traditional_from_phases_ms"] = _best(lambda: mf_unwrap(phi, (1, 48), width=912, valid=valid), repeats)
    out["filtered_ms"] = _best(lambda: filtered_order("mf", phi[0], phi[1], (1, 48), valid, width=912), repeats)
    out["features_ms"] = _best(lambda: FF.make_inputs("physics", "mf", prior, phi[0], phi[1], mods[0], mods[1], trad,
                                                      ok, (1, 48), **lay), repeats)
    out["forward_torch_ms"] = _best(lambda: torch_pred.logits(xt), repeats)
    out["forward_ort_ms"] = _best(lambda: ort_pred.logits(x), repeats)
    for name, model in (("torch", torch_pred), ("ort", ort_pred)):
        out[f"whole_{name}_ms"] = _best(lambda m=model: unwrap_learned("mf", phi[0], phi[1], mods[0], mods[1], valid,
                                                                       (1, 48), width=912, model=m,
                                                                       on_outside="ignore"), repeats)
    # everything but the forward (its logits stored): what the whole path adds, without the
    # forward's own noise on a shared machine
    stored = _StoredLogits(torch_pred, torch_pred.logits(xt))     # the torch path's layouts
    out["whole_minus_forward_ms"] = _best(lambda: unwrap_learned("mf", phi[0], phi[1], mods[0], mods[1], valid, (1, 48),
                                                                 width=912, model=stored, on_outside="ignore"), repeats)
    return out


class _StoredLogits:
    """A predictor returning fixed logits (of the same frame): the learned path without its forward."""

    backend = "stored"

    def __init__(self, pred, logits):
        self.arch, self.meta, self._y = pred.arch, pred.meta, logits
        self.input_layout, self.multiple = getattr(pred, "input_layout", "nchw"), getattr(pred, "multiple", 1)

    def logits(self, x):
        return self._y


# the baseline checkout (920e6f4) is older than the floor plan: its module path
_OLD_LEARNED = ("import json, sys\nfrom unwrap.learned.evaluate import speed_table\n"
                "from unwrap.learned.infer import shipped_model_path\n"
                "print(json.dumps(speed_table(shipped_model_path(), repeats=int(sys.argv[1]))))\n")


def baseline_learned(root: Path, repeats: int) -> dict:
    """The older checkout's own learned speed table (its code: torch features, no ONNX)."""
    p = subprocess.run([sys.executable, "-c", _OLD_LEARNED, str(repeats)], capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=str(root)), cwd=root, timeout=3600)
    return json.loads(p.stdout.strip().splitlines()[-1]) if p.returncode == 0 else {}


def mrcal_anchor(views: int, repeats: int) -> dict:
    """bench.ba_scale's single-camera comparison on ``views`` simulated views: our solve and mrcal's."""
    from bench.ba_scale import _run_child

    r = _run_child([views, "single", 5, repeats, 1], str(ROOT))
    j = _run_child([views, "joint", 5, repeats, 0], str(ROOT))
    return {"ours_single_s": r.get("solve_s"), "mrcal_single_s": r.get("mrcal_s"), "ours_joint_s": j.get("solve_s")}


def _fmt(v, spec=".3g"):
    return "-" if v is None or v != v else format(v, spec)


def cli_rows(args, roots, tmp: Path, obs_json: Path, cap: Path, onnx_path: Path) -> list:
    """(name, wall s, peak MB, solve s, error) of the command-line rows."""
    rows = []

    def cli(label, argv, out_name, only_after=False):
        for tag, root in roots[:1] if only_after else roots:
            r = measure(argv, root, tmp / f"{out_name}_{tag}", args.repeats)   # wall and stages: its fastest run
            rows.append((f"{label} [{tag}]", min(r["walls"]), r["peak_mb"], r["solve_s"], r["error"], r["stages"]))

    paper = [DP_TPU / "CamCalibResult_real.mat", DP_TPU / "PrjCalibResult_real.mat"]
    if all(p.is_file() for p in paper):
        cli("calib run --observations, paper's 9 views", ["run", "--observations", *paper, "-q"], "run9")
    cli(f"calib run, {args.views}-view joint session", ["run", "--observations", obs_json, "-q"], f"run{args.views}")
    W, H = args.size
    cli(f"calib unwrap (traditional), {W}x{H}", ["unwrap", cap], "trad")
    cli(f"calib unwrap --model learned (torch), {W}x{H}", ["unwrap", cap, "--model", "learned"], "torch")
    cli(f"calib unwrap --model model.onnx (onnxruntime), {W}x{H}", ["unwrap", cap, "--model", onnx_path], "onnx",
        only_after=True)
    return rows


def print_cli(rows, anchors) -> None:
    print("## Command line (fresh process each)\n")
    print("| command | wall s | peak MB | solve s (its own) | error |\n|---|---:|---:|---:|---|")
    for name, w, pk, s, e, *_ in rows:
        print(f"| {name} | {_fmt(w)} | {_fmt(pk, '.0f')} | {_fmt(s)} | {e or ''} |")
    staged = [(name, w, st) for name, w, _, _, _, st in rows if st]
    if staged:         # calib run's own stage profile (calibration.json "run"; bench.calib_speed has more)
        print("\n| calib run: stages s (fastest run) | " + " | ".join(f"{name}" for name, _, _ in staged) + " |")
        print("|---|" + "---:|" * len(staged))
        for key in dict.fromkeys(k for _, _, st in staged for k in st):
            print(f"| {key} | " + " | ".join(_fmt(st.get(key)) for _, _, st in staged) + " |")
        print("| rest (start-up, imports, reading, json; min wall - stages) | "
              + " | ".join(_fmt(w - sum(st.values())) for _, w, st in staged) + " |")
    print("\n## Solve anchors (bench.ba_scale, simulated views, same run)\n")
    print("| views | ours joint solve s | ours single-camera solve s | mrcal single-camera s |\n|---:|---:|---:|---:|")
    for v, a in anchors.items():
        print(f"| {v} | {_fmt(a['ours_joint_s'])} | {_fmt(a['ours_single_s'])} | {_fmt(a['mrcal_single_s'])} |")


def batch_rows(args, tmp: Path, onnx_path: Path) -> None:
    """calib unwrap over the folder of captures: wall, captures/s, peak (printed)."""
    W, H = args.size
    print(f"\n## Batch: calib unwrap over a folder of {args.captures} captures {W}x{H} (one process, "
          "no previews; wall includes start-up)\n")
    print("| decode | wall s | captures/s | peak MB |\n|---|---:|---:|---:|")
    for k, (label, extra) in enumerate((("traditional", []), ("learned, onnxruntime", ["--model", onnx_path]),
                                        ("learned, torch", ["--model", "learned"]))):
        r = run_cli(["unwrap", tmp / "caps", *extra, "-o", tmp / f"batch_{k}", "-q", "--no-previews"], ROOT, 1)
        print(f"| {label} | {_fmt(r['wall_s'])} | {_fmt(args.captures / r['wall_s'])} | {_fmt(r['peak_mb'], '.0f')} |"
              + (f" error: {r['error']}" if r["error"] else ""))


_LEARNED_ROWS = (("traditional_from_frames_ms", "traditional TPU from frames (anchor)", "traditional_from_frames_ms"),
                 ("traditional_from_phases_ms", "traditional TPU from phases", "traditional_from_phases_ms"),
                 ("filtered_ms", "filtered 15x15 baseline", "filtered_ms"),
                 ("features_ms", "input features (both plane fits, all channels; torch's layout)", None),
                 ("forward_torch_ms", "network forward, torch (as the path runs it)", "network_forward_ms"),
                 ("forward_ort_ms", "network forward, onnxruntime", None),
                 ("whole_torch_ms", "whole learned path, torch", "learned_total_ms"),
                 ("whole_ort_ms", "whole learned path, onnxruntime", None),
                 ("whole_minus_forward_ms", "whole learned path without the forward (stored logits)", None))


def print_learned(lr: dict, old: dict, repeats: int) -> None:
    anchor = lr["traditional_from_frames_ms"]
    print(f"\n## Learned path, one 640x480 orientation, MF (1, 48), 12 steps (torch threads {lr['threads_torch']}, "
          f"onnxruntime {lr['providers_ort']}; minimum of {repeats} calls)\n")
    print("| part | ms | x traditional (frames) | before ms (baseline's code) | before x its traditional |\n"
          "|---|---:|---:|---:|---:|")
    old_anchor = old.get("traditional_from_frames_ms")
    for key, name, okey in _LEARNED_ROWS:
        o = old.get(okey) if okey else None
        if key not in lr:
            continue
        print(f"| {name} | {lr[key]:.1f} | {lr[key] / anchor:.1f} | {_fmt(o, '.1f')} | "
              f"{_fmt(o / old_anchor if o and old_anchor else None, '.1f')} |")
    print(f"\nwhole path / forward: torch {lr['whole_torch_ms'] / lr['forward_torch_ms']:.2f}x, onnxruntime "
          f"{lr['whole_ort_ms'] / lr['forward_ort_ms']:.2f}x; onnxruntime / torch forward "
          f"{lr['forward_ort_ms'] / lr['forward_torch_ms']:.2f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--views", type=int, default=100, help="views of the simulated joint session")
    ap.add_argument("--captures", type=int, default=4, help="captures in the batch row")
    ap.add_argument("--baseline", help="an older checkout to run beside (before / after columns)")
    ap.add_argument("--quick", action="store_true", help="1 repeat, 20 views, a 450 x 350 capture, batch of 2")
    args = ap.parse_args(argv)
    args.size = (900, 700)
    if args.quick:
        args.repeats, args.views, args.captures, args.size = 1, 20, 2, (450, 350)
    base = Path(args.baseline).resolve() if args.baseline else None
    print(f"machine: {os.cpu_count()} CPU(s), load average {os.getloadavg()[0]:.1f} at start (shared: read the "
          f"ratios); minimum of {args.repeats} run(s)\n")
    with tempfile.TemporaryDirectory(prefix="deploy_speed_") as tmp:
        tmp = Path(tmp)
        from bench.ba_scale import _simulate
        from calib.observations import write_observations_json
        from unwrap.learned.runtime import export_onnx

        obs_json = write_observations_json(_simulate(args.views), tmp / f"obs{args.views}.json")
        onnx_path = export_onnx("learned", tmp / "model.onnx")
        cap = write_capture(tmp / "caps" / "c0", args.size, seed=0)
        for i in range(1, args.captures):
            write_capture(tmp / "caps" / f"c{i}", args.size, seed=i)
        roots = [("after", ROOT)] + ([("before", base)] if base else [])
        rows = cli_rows(args, roots, tmp, obs_json, cap, onnx_path)
        print_cli(rows, {v: mrcal_anchor(v, args.repeats) for v in (9, args.views)})
        batch_rows(args, tmp, onnx_path)
        reps = max(args.repeats, 3)
        print_learned(learned_rows(onnx_path, reps), baseline_learned(base, reps) if base else {}, reps)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
