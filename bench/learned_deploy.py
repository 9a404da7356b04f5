"""The learned path at deployment speed (issue 22, part 2): before / after in the same run, and the
forward pass of candidate architectures a retrain could choose.

    python -m bench.learned_deploy [--repeats 5] [--baseline DIR] [--arch] [--no-cli] [--cli-only] [--quick]

Tables (times are minima over ``repeats`` calls; the machine is shared, so read each row against
the anchor measured in the same process):

1. one 640 x 480 orientation, MF (1, 48), 12 steps: the rows of
   :func:`bench.deploy_speed.learned_rows` (traditional decode from the frames = the anchor,
   filtered 15 x 15 baseline, input features, network forward on torch and onnxruntime, the whole
   learned path on each and without its forward), for this checkout and, with ``--baseline DIR`` (an older checkout:
   ``git archive REV | tar -x -C DIR``), for that one in a subprocess of the same run;
2. ``calib unwrap`` on a 900 x 700 capture (:func:`bench.deploy_speed.write_capture`), fresh
   process each: traditional (the anchor), ``--model model.onnx`` (and with ``--low-memory``, this
   checkout only) and ``--model learned`` (torch): wall time, CPU time (user + system of the process,
   all its threads: steadier than the wall on a shared machine) and peak resident memory, for both
   checkouts, the runs of the two interleaved (``--cli-only``: this table alone);
3. ``--arch``: multiply-adds (:func:`unwrap.learned.network.count_macs`), parameters and forward ms
   (onnxruntime and torch, untrained weights: the time does not depend on the values) of the
   shipped architecture (the anchor) and of lighter ``[model]`` options, at 640 x 480.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: ``[model]`` overrides of the candidate architectures (the first: the shipped one).
ARCHS = ((), ("model.width=12",), ("model.width=8",), ("model.conv=separable",), ("model.max_width=32",),
         ("model.width=8", "model.norm=batch"), ("model.width=8", "model.norm=batch", "model.stem=strided"),
         ("model.width=8", "model.norm=batch", "model.stem=strided", "model.conv=separable"))
_ROWS_CHILD = ("import json, sys\nfrom bench.deploy_speed import learned_rows\n"
               "print('ROWS ' + json.dumps(learned_rows(sys.argv[1], int(sys.argv[2]))))\n")


def rows_in(root: Path, onnx_path: Path, repeats: int) -> dict:
    """:func:`bench.deploy_speed.learned_rows` of the checkout at ``root``, in a subprocess."""
    p = subprocess.run([sys.executable, "-c", _ROWS_CHILD, str(onnx_path), str(repeats)], capture_output=True,
                       text=True, env=dict(os.environ, PYTHONPATH=str(root)), cwd=root, timeout=3600)
    for line in p.stdout.splitlines():
        if line.startswith("ROWS "):
            return json.loads(line[5:])
    sys.stderr.write(f"{root}: learned rows failed: {(p.stderr.strip().splitlines() or ['?'])[-1]}\n")
    return {}


def arch_rows(repeats: int, tmp: Path) -> list:
    """(overrides, parameters, GMACs, onnxruntime ms, torch ms) per candidate of :data:`ARCHS`."""
    import numpy as np
    import torch

    from bench.deploy_speed import _best
    from unwrap.learned.checkpoint import arch_from_config, build_model
    from unwrap.learned.config import resolve_config
    from unwrap.learned.network import count_macs, count_parameters
    from unwrap.learned.runtime import OnnxPredictor, export_onnx

    out = []
    for k, ov in enumerate(ARCHS):
        cfg = resolve_config(None, [*ov, "data.synthetic_samples=1"])
        arch = arch_from_config(cfg.model)
        net = build_model(arch).eval()
        C = int(arch["in_channels"])
        x = np.random.default_rng(0).standard_normal((1, C, 480, 640)).astype(np.float32)
        path = export_onnx((net, {"arch": arch, "meta": {}}), tmp / f"arch{k}.onnx")
        ort = OnnxPredictor(path)
        with torch.inference_mode():
            xt = torch.from_numpy(x)
            t_torch = _best(lambda: net(xt), repeats)
        out.append((" ".join(ov) or "default config (width 16, full 3x3)", count_parameters(net),
                    count_macs(net, C, (480, 640)) / 1e9, _best(lambda: ort.logits(x), repeats), t_torch))
    return out


def run_timed(args, root: Path) -> dict:
    """:func:`bench.deploy_speed.run_cli` once, plus ``cpu_s``: the child's user + system seconds."""
    import resource

    from bench.deploy_speed import run_cli

    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    out = run_cli(args, root, 1)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return dict(out, cpu_s=(r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime))


def _f(v, spec=".1f"):
    return "-" if v is None or v != v else format(v, spec)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--baseline", help="an older checkout run beside (before columns)")
    ap.add_argument("--arch", action="store_true", help="also time the candidate architectures")
    ap.add_argument("--no-cli", action="store_true", help="skip the calib unwrap rows")
    ap.add_argument("--cli-only", action="store_true", help="only the calib unwrap rows (no 640x480 rows)")
    ap.add_argument("--quick", action="store_true", help="1 repeat, no calib unwrap rows, no architectures")
    args = ap.parse_args(argv)
    if args.quick:
        args.repeats, args.no_cli, args.arch = 1, True, False
    from bench.deploy_speed import _LEARNED_ROWS, bytecode_note, write_capture
    from unwrap.learned.runtime import export_onnx

    base = Path(args.baseline).resolve() if args.baseline else None
    print(f"machine: {os.cpu_count()} CPU(s), load average {os.getloadavg()[0]:.1f} at start (shared: read the "
          f"ratios to the anchors); minimum of {args.repeats} calls")
    print(f"{bytecode_note()}\n")
    with tempfile.TemporaryDirectory(prefix="learned_deploy_") as tmp:
        tmp = Path(tmp)
        onnx_path = export_onnx("learned", tmp / "model.onnx")
        after = {} if args.cli_only else rows_in(ROOT, onnx_path, args.repeats)
        before = rows_in(base, onnx_path, args.repeats) if base and not args.cli_only else {}
        if not args.cli_only:
            print("## One 640x480 orientation, MF (1, 48), 12 steps (ms; x = times the traditional decode of the "
                  "same process)\n")
            print("| part | after ms | after x | before ms | before x |\n|---|---:|---:|---:|---:|")
        a0, b0 = after.get("traditional_from_frames_ms"), before.get("traditional_from_frames_ms")
        for key, label, _ in (_LEARNED_ROWS if not args.cli_only else ()):     # the rows of bench.deploy_speed
            a, b = after.get(key), before.get(key)
            print(f"| {label} | {_f(a)} | {_f(a / a0 if a and a0 else None, '.2f')} | {_f(b)} | "
                  f"{_f(b / b0 if b and b0 else None, '.2f')} |")
        for tag, r in (("after", after), ("before", before)):
            if r:
                print(f"\n{tag}: whole path / forward: torch {r['whole_torch_ms'] / r['forward_torch_ms']:.2f}x, "
                      f"onnxruntime {r['whole_ort_ms'] / r['forward_ort_ms']:.2f}x")
        if not args.no_cli:
            cap = write_capture(tmp / "cap", (900, 700), seed=0)
            print("\n## calib unwrap on a 900x700 capture (fresh process each; min wall / min CPU / max peak of "
                  f"{args.repeats} runs, the checkouts and commands interleaved; load average "
                  f"{os.getloadavg()[0]:.1f} at the start of these runs)\n")
            print("| command | checkout | wall s | x traditional | CPU s | x traditional | peak MB | error |\n"
                  "|---|---|---:|---:|---:|---:|---:|---|")
            rows = [("traditional (anchor)", []), ("--model model.onnx", ["--model", onnx_path]),
                    ("--model model.onnx --low-memory", ["--model", onnx_path, "--low-memory"]),
                    ("--model learned (torch)", ["--model", "learned"])]
            checkouts = [(tag, root) for tag, root in (("after", ROOT), ("before", base)) if root is not None]
            runs = {}
            for rep in range(args.repeats):     # interleaved: a change of load hits both checkouts alike
                for label, extra in rows:
                    for tag, root in (checkouts if rep % 2 == 0 else checkouts[::-1]):
                        if tag == "before" and "--low-memory" in extra:     # an option of this checkout
                            continue
                        runs.setdefault((tag, label), []).append(run_timed(
                            ["unwrap", cap, *extra, "-o", tmp / f"out_{tag}_{len(extra)}_{label[8:12]}", "-q"], root))
            for tag, _ in checkouts:
                trad = trad_cpu = None
                for label, _ in rows:
                    if (tag, label) not in runs:
                        continue
                    rs = runs[(tag, label)]
                    wall, peak = min(r["wall_s"] for r in rs), max(r["peak_mb"] for r in rs)
                    cpu = min(r["cpu_s"] for r in rs)
                    err = next((r["error"] for r in rs if r["error"]), None)
                    trad, trad_cpu = trad or wall, trad_cpu or cpu
                    print(f"| {label} | {tag} | {_f(wall, '.2f')} | {_f(wall / trad, '.2f')} | {_f(cpu, '.2f')} | "
                          f"{_f(cpu / trad_cpu, '.2f')} | {_f(peak, '.0f')} | {err or ''} |")
            print(f"\nload average {os.getloadavg()[0]:.1f} at the end")
        if args.arch:
            print("\n## Candidate architectures, 640x480 forward (untrained weights; onnxruntime and torch, "
                  "2 threads)\n")
            print("| [model] | parameters | GMACs | onnxruntime ms | x shipped | torch ms | x shipped |\n"
                  "|---|---:|---:|---:|---:|---:|---:|")
            rows = arch_rows(args.repeats, tmp)
            o0, t0 = rows[0][3], rows[0][4]
            for name, n, g, o, t in rows:
                print(f"| {name} | {n:,} | {g:.2f} | {o:.1f} | {o / o0:.2f} | {t:.1f} | {t / t0:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
