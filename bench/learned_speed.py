"""What the learned unwrapping costs in time, beside the traditional paths it replaces.

Run: ``python -m bench.learned_speed [--model PATH] [--repeats N] [--threads T]`` (``--quick``: 2 repeats),
``... --stages [--baseline DIR] [--rounds R]``, ``... --variants [--model PATH ...]``.

One orientation of a 640 x 480 frame, MF (1, 48), 12 steps (`experiments.learned_evaluation.speed_table`):
the traditional TPU from frames (fused kernel: wrapped phases + MF in one pass) and from wrapped
phases (the prior and its rounding), the filtered baseline (15 x 15 plane fit of the unit phase),
the network alone as the path runs it (on the CPU: channels-last, BatchNorm folded, its input in
that layout) and the whole learned path (prior + input features + network + decode), and their
ratio (issue 22's goals: forward <= 40 ms on 2 cores, whole path <= 2x the forward). Every
time is the minimum over ``repeats`` calls in the same process, so a shared machine's load hits
all rows alike; the ratios to the traditional rows are what to read. Training throughput
(samples/s of 128 x 128 crops, forward + backward + AdamW step, batch 8) is measured the same way.

``--stages``: where the learned path's time goes, stage by stage, with the torch predictor the path
loads (on the CPU channels-last, BatchNorm folded, the features written in its layout), each stage
timed alone on the same frame: the range check (fringe period), the traditional decode (prior,
orders), the input features (their two plane fits also alone), the heap trim, the forward, the
decode; then the whole path (torch, and onnxruntime on an exported graph) and whole / forward.
``--baseline DIR`` (``git archive REV | tar -x -C DIR``): the same stages with that checkout's code
in a subprocess; the checkouts alternate over ``--rounds`` subprocesses each and every number is
the minimum over all of them (a load change on the shared machine hits both alike).

``--variants``: per checkpoint (``--model``, repeatable; default the shipped one), the CPU
forward as the plain network (NCHW), channels-last with its input already so, channels-last
converting an NCHW input, BatchNorm folded, and both (:mod:`unwrap.learned.cpu_net`), interleaved,
with the largest logit difference to the plain forward.
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


def training_samples_per_s(model_path, repeats: int = 5, crop: int = 128, batch: int = 8) -> float:
    import torch

    from unwrap.learned.checkpoint import build_model, read_checkpoint

    ck = read_checkpoint(model_path)
    net = build_model(ck["arch"]).train()
    opt = torch.optim.AdamW(net.parameters(), lr=1e-4)
    x = torch.randn(batch, ck["arch"]["in_channels"], crop, crop)
    best = float("inf")
    for i in range(repeats + 1):
        t = time.perf_counter()
        net(x).square().mean().backward()
        opt.step()
        opt.zero_grad()
        if i:
            best = min(best, time.perf_counter() - t)
    return batch / best


# Run as the child's source in either checkout (an older one lacks this module): self-contained.
_CHILD = r'''
import json, sys, time
import numpy as np
import torch
torch.set_num_threads(int(sys.argv[3]))
from experiments.learned_evaluation import speed_scene
from unwrap.learned import fast_features as FF
from unwrap.learned import infer as I
from unwrap.learned.runtime import load_predictor
from unwrap.memory import trim_heap
from unwrap.temporal import decode_pair

repeats = int(sys.argv[2])
cpu = {}
def best(f, key=None):
    f()
    ts, cs = [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time(); f()
        ts.append(time.perf_counter() - t); cs.append(time.process_time() - c)
    if key:
        cpu[key] = 1e3 * min(cs)
    return 1e3 * min(ts)

stacks, phi, mods, valid = speed_scene((480, 640))
f, width = (1.0, 48.0), 912.0
pred, ort = load_predictor("learned"), load_predictor(sys.argv[1])
layout, mult = getattr(pred, "input_layout", "nchw"), getattr(pred, "multiple", 1)
kw = {"layout": layout, "multiple": mult} if layout != "nchw" or mult != 1 else {}
prior, trad, ok = decode_pair("mf", phi[0], phi[1], *f, width, valid)
def feats():
    return FF.make_inputs("physics", "mf", prior, phi[0], phi[1], mods[0], mods[1], trad, ok, f, **kw)
x, ok2 = feats()
z = pred.logits(x)[..., :480, :640]
K = int(pred.arch["max_correction"])
out = {"layout": layout, "threads": torch.get_num_threads()}
out["range check (fringe period)"] = best(lambda: I.check_frequency_range(pred.meta, "mf", f, phi[1], valid,
                                                                          on_outside="ignore"), "range check (fringe period)")
if hasattr(I, "_decode_pair"):     # the path's own (the C replica for MF where built)
    trad_decode = lambda: I._decode_pair("mf", phi[0], phi[1], *f, width, valid)
else:
    trad_decode = lambda: decode_pair("mf", np.nan_to_num(phi[0]), np.nan_to_num(phi[1]), *f, width, valid)
out["traditional decode (prior, orders)"] = best(trad_decode, "traditional decode (prior, orders)")
out["input features"] = best(feats, "input features")
Phi = FF.coarse_phase("mf", phi[0].astype(np.float32).astype(np.float64), phi[1], *f, width)[0]
out["  of which the two plane fits"] = best(lambda: FF.plane_filter(Phi, ok2), "  of which the two plane fits")
out["heap trim"] = best(trim_heap)
out["forward, torch"] = best(lambda: pred.logits(x))
out["decode (softmax, class, orders)"] = best(lambda: FF.decode(z, trad, ok2, f[1], "physics", K, None),
                                              "decode (softmax, class, orders)")
whole = lambda m: (lambda: I.unwrap_learned("mf", phi[0], phi[1], mods[0], mods[1], valid, f, width=width,
                                            model=m, on_outside="ignore"))
out["whole path, torch"] = best(whole(pred))
xo = ort.prepare(np.ascontiguousarray(x))
out["forward, onnxruntime"] = best(lambda: ort.logits(xo))
out["whole path, onnxruntime"] = best(whole(ort))
out["cpu"] = cpu
print("STAGES " + json.dumps(out))
'''

#: Stage rows in print order (the keys of the child's JSON).
STAGES = ("range check (fringe period)", "traditional decode (prior, orders)", "input features",
          "  of which the two plane fits", "heap trim", "forward, torch", "decode (softmax, class, orders)",
          "whole path, torch", "forward, onnxruntime", "whole path, onnxruntime")


def stages_in(root: Path, onnx_path: Path, repeats: int, threads: int) -> dict:
    """The child's stage times (ms) with the code of the checkout at ``root``; {} on failure."""
    p = subprocess.run([sys.executable, "-c", _CHILD, str(onnx_path), str(repeats), str(threads)],
                       capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(root)), cwd=root,
                       timeout=3600)
    for line in p.stdout.splitlines():
        if line.startswith("STAGES "):
            return json.loads(line[7:])
    sys.stderr.write(f"{root}: stages failed: {(p.stderr.strip().splitlines() or ['?'])[-1]}\n")
    return {}


def _merge_min(acc: dict, new: dict) -> dict:
    for k, v in new.items():
        if isinstance(v, dict):
            _merge_min(acc.setdefault(k, {}), v)
        else:
            acc[k] = min(acc[k], v) if isinstance(v, float) and k in acc else v
    return acc


def forward_variants(path, repeats: int, rounds: int) -> list:
    """(variant, ms, max |logit - plain|) of the CPU forward variants of one checkpoint (module docstring)."""
    import time

    import numpy as np
    import torch

    from unwrap.learned.checkpoint import load_model
    from unwrap.learned.cpu_net import prepare_for_cpu

    net, ck = load_model(path, "cpu")
    x = torch.from_numpy(np.random.default_rng(0).standard_normal((1, int(ck["arch"]["in_channels"]), 480, 640))
                         .astype(np.float32))
    xcl = x.contiguous(memory_format=torch.channels_last)
    cl, fold = prepare_for_cpu(net, channels_last=True, fold=False), prepare_for_cpu(net, channels_last=False, fold=True)
    both = prepare_for_cpu(net, channels_last=True, fold=True)
    variants = [("NCHW (plain network)", lambda: net(x)), ("channels-last, input channels-last", lambda: cl(xcl)),
                ("channels-last, NCHW input converted", lambda: cl(x.contiguous(memory_format=torch.channels_last))),
                ("BatchNorm folded, NCHW", lambda: fold(x)), ("channels-last + folded, input channels-last",
                                                               lambda: both(xcl))]
    times = {name: [] for name, _ in variants}
    with torch.inference_mode():
        ref = net(x)
        diffs = {name: float((f() - ref).abs().max()) for name, f in variants}
        for _ in range(rounds):             # interleaved: a load change hits every variant alike
            for name, f in variants:
                for _ in range(repeats):
                    t = time.perf_counter()
                    f()
                    times[name].append(time.perf_counter() - t)
    return [(name, 1e3 * min(times[name]), diffs[name]) for name, _ in variants]


def stage_table(args) -> None:
    """Print the ``--stages`` table (module docstring)."""
    from unwrap.learned.runtime import export_onnx

    base = Path(args.baseline).resolve() if args.baseline else None
    load0 = os.getloadavg()[0]
    after, before = {}, {}
    with tempfile.TemporaryDirectory(prefix="learned_stages_") as tmp:
        onnx_path = export_onnx("learned", Path(tmp) / "model.onnx")
        for r in range(args.rounds):
            order = [(ROOT, after), (base, before)]
            for root, acc in (order if r % 2 == 0 else order[::-1]):
                if root is not None:
                    _merge_min(acc, stages_in(root, onnx_path, args.repeats, args.threads or 2))
    print(f"## Learned path stage by stage, one 640x480 orientation, MF (1, 48) ({after.get('threads')} torch "
          f"threads; load average {load0:.1f} -> {os.getloadavg()[0]:.1f}; minimum of {args.repeats} calls x "
          f"{args.rounds} processes per checkout; input layout after: {after.get('layout')}, before: "
          f"{before.get('layout', '-')})\n")
    print("| stage | after ms | before ms | after / before | after CPU ms | before CPU ms | CPU after / before |\n"
          "|---|---:|---:|---:|---:|---:|---:|")
    fmt = lambda v, spec=".1f": "-" if v is None or v != v else format(v, spec)  # noqa: E731
    ca, cb = after.get("cpu", {}), before.get("cpu", {})
    for k in STAGES:
        a, b, c, d = after.get(k), before.get(k), ca.get(k), cb.get(k)
        print(f"| {k} | {fmt(a)} | {fmt(b)} | {fmt(a / b if a and b else None, '.2f')} | {fmt(c)} | {fmt(d)} | "
              f"{fmt(c / d if c and d else None, '.2f')} |")
    print("\n(CPU: the process's CPU time during the stage, all its threads (the C stages run on two), for the "
          "stages without torch: what the load does not inflate as much as the wall time)")
    for tag, d in (("after", after), ("before", before)):
        if d.get("forward, torch"):
            print(f"\n{tag}: whole path / forward: torch {d['whole path, torch'] / d['forward, torch']:.2f}x, "
                  f"onnxruntime {d['whole path, onnxruntime'] / d['forward, onnxruntime']:.2f}x; whole minus "
                  f"forward: torch {d['whole path, torch'] - d['forward, torch']:.1f} ms")


def variant_tables(paths, repeats: int, rounds: int, threads: int) -> None:
    """Print the ``--variants`` tables (module docstring)."""
    from unwrap.learned.checkpoint import read_checkpoint

    for path in paths:
        arch = read_checkpoint(path)["arch"]
        print(f"\n## CPU forward variants, {path} (width {arch['width']}, norm {arch.get('norm', 'group')}, stem "
              f"{arch.get('stem', 'shuffle')}); 640x480, {threads} threads, load {os.getloadavg()[0]:.1f}\n")
        rows = forward_variants(path, repeats, rounds)
        t0 = rows[0][1]
        print("| forward | ms | x NCHW | max abs logit difference |\n|---|---:|---:|---:|")
        for name, t, d in rows:
            print(f"| {name} | {t:.1f} | {t / t0:.2f} | {d:.1e} |")


def main(argv=None) -> int:
    import torch

    from experiments.learned_evaluation import speed_table
    from unwrap.learned.infer import shipped_model_path

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", action="append", default=None, help="checkpoint (default: the shipped model); "
                   "repeatable with --variants")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--threads", type=int, default=0, help="torch threads (default: torch's; --stages: 2)")
    p.add_argument("--quick", action="store_true", help="2 repeats (checks that the benchmark runs)")
    p.add_argument("--stages", action="store_true", help="the stage-by-stage table instead (module docstring)")
    p.add_argument("--baseline", help="with --stages: an older checkout timed beside (before columns)")
    p.add_argument("--rounds", type=int, default=3, help="with --stages / --variants: rounds, interleaved")
    p.add_argument("--variants", action="store_true", help="the CPU forward variants table instead")
    args = p.parse_args(argv)
    if args.quick:
        args.repeats, args.rounds = 2, 1
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.stages or args.variants:
        if args.stages:
            stage_table(args)
        if args.variants:
            variant_tables(args.model or [shipped_model_path()], args.repeats, args.rounds, torch.get_num_threads())
        return 0
    model = (args.model or [None])[0] or shipped_model_path()
    sp = speed_table(model, repeats=args.repeats)
    trad = sp["traditional_from_frames_ms"]
    print(f"one orientation, {sp['size']}, MF (1, 48), 12 steps; {sp['threads']} torch thread(s); minimum of "
          f"{args.repeats} calls")
    print(f"{'path':34s} {'ms':>9s} {'x traditional (frames)':>24s}")
    for key, name in (("traditional_from_frames_ms", "traditional TPU from frames"),
                      ("traditional_from_phases_ms", "traditional TPU from phases"),
                      ("filtered_ms", "filtered 15x15 from phases"),
                      ("network_forward_ms", f"network forward ({sp['forward_layout']} input)"),
                      ("learned_total_ms", "learned from phases (all steps)")):
        print(f"{name:34s} {sp[key]:9.1f} {sp[key] / trad:24.1f}")
    print(f"whole learned path / network forward: {sp['whole_over_forward']:.2f}x (goal <= 2; forward goal <= 40 ms "
          f"on 2 cores)")
    print(f"training: {training_samples_per_s(model, args.repeats):.1f} samples/s (128x128 crops, batch 8)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
