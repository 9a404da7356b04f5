"""The learned unwrapping on a GPU beside the CPU (issue 22's GPU rows): forward and whole-path ms
per frame in fp32 / fp16 / bf16, a batch of frames, the orders each variant gives, training
samples/s.

Run:

    python -m bench.learned_gpu --save-frames FRAMES.npz [--test H5 ...]   # real frames, where ../shared/data is
    python -m bench.learned_gpu [--frames FRAMES.npz] [--model NAME=PATH ...] [--json OUT] [--quick]

Without a CUDA device only the CPU rows are measured (the table says so). Every row is the minimum
over ``--repeats`` calls in one process (CUDA synchronised before the clock stops), so the ratios
between rows of one run are what to read; the machine (CPU model, cores, GPU name) heads the table.

Rows, per model:

- **forward** of one 640 x 480 frame (zeros; the network's cost does not depend on the values):
  torch on the CPU with 2 threads (the deployment target of docs/speed.md) and with all cores
  (the plain network: the reference), the CPU forward the path runs (channels-last, BatchNorm
  folded: :mod:`unwrap.learned.cpu_net`; its orders and whole path counted like the CUDA rows),
  onnxruntime on the CPU with 2 threads, torch on CUDA in fp32, fp16 and bf16 (autocast), and
  channels-last; ``batch 8``: 8 frames in one call, per frame.
- **whole path** per frame (:func:`unwrap.learned.infer.unwrap_learned`: traditional prior on the
  CPU; input features and decode on the CPU, or on CUDA for an MF frame on a CUDA predictor; the
  forward where the predictor runs) on each frame of
  ``--frames``, beside the traditional decode of the same pair (the anchor: ``decode_pair``).
- **orders**: on every valid pixel of each frame, the orders of each CUDA variant against torch fp32
  on the CPU. Differing pixels are counted; where they differ, the CPU's logit margin between its
  two most probable classes (a tie within half precision's rounding, ~1e-3 relative in bf16, is what
  moves a pixel) is reported, and each variant's error rate against the frame's reference.
- **training**: samples/s of batches of 128 x 128 crops, forward + backward + AdamW step, CPU
  (2 threads) vs CUDA, fp32 and under the training's AMP (bfloat16 autocast).

Frames (``--save-frames``): the pyramid (MF 1/16, both orientations) and the SLStudio skull (MF) of
../shared/data, and from each ``--test`` dataset file (a twin export) its first MF and MW frames,
with their reference orders: float64 phases (the order depends on their last bits at high
frequency), so the file is tens of MB; made where the data is, carried to the GPU machine.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

SIZE = (480, 640)
KEYS = ("phase_low", "phase_high", "m_low", "m_high", "valid", "ref")


# ---------------------------------------------------------------- frames
def save_frames(out, tests=(), work=None) -> list[str]:
    """Write the real and twin frames (module docstring) to ``out`` (npz, atomically); their names."""
    from bench.retrain_compare import _dataset_items
    from bench.spatial_unwrap import _pyramid_items, _skull_items
    from unwrap.safe_output import atomic_path

    work = Path(work or Path(out).parent)
    items = [dict(it, method="mf") for it in _pyramid_items() + _skull_items(work)]
    if not items:
        print("no real capture found under ../shared/data (pyramid, SLStudio skull): twin frames only", file=sys.stderr)
    for t in tests:
        got = _dataset_items(t, (48.0,), ("mf", "mw"))
        for m in ("mf", "mw"):
            items += [it for it in got if it["method"] == m][:1]
    arrays, meta = {}, []
    for i, it in enumerate(items):
        for k in KEYS:
            arrays[f"{i}_{k}"] = np.asarray(it[k])
        meta.append(dict(name=it["name"], method=it["method"], freqs=list(map(float, it["freqs"])),
                         width=float(it["width"])))
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    with atomic_path(Path(out)) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)
    return [m["name"] for m in meta]


def load_frames(path) -> list[dict]:
    """The frames written by :func:`save_frames`."""
    with np.load(path) as z:
        meta = json.loads(bytes(z["meta"]).decode())
        return [dict(m, **{k: z[f"{i}_{k}"] for k in KEYS}) for i, m in enumerate(meta)]


def ramp_frame() -> dict:
    """The speed rows' noisy linear ramp (MF 1/48, 640 x 480) as a frame; reference: its true order."""
    from experiments.learned_evaluation import speed_scene

    _, phi, mods, valid = speed_scene(SIZE)
    rng = np.random.default_rng(0)             # speed_scene's projector columns: its first draw
    u = np.tile(np.linspace(100, 800, SIZE[1]), (SIZE[0], 1)) + rng.normal(0, 0.2, SIZE)
    ref = np.where(valid, np.rint((2 * np.pi * 48 * u / 912 - phi[1]) / (2 * np.pi)), -1).astype(np.int64)
    return dict(name="ramp 640x480 MF 1/48", method="mf", freqs=[1.0, 48.0], width=912.0, phase_low=phi[0],
                phase_high=phi[1], m_low=mods[0], m_high=mods[1], valid=valid, ref=ref)


# ---------------------------------------------------------------- timing
def _sync(device):
    if str(device).startswith("cuda"):
        import torch
        torch.cuda.synchronize()


def best_ms(fn, repeats: int, device="cpu") -> float:
    """Minimum over ``repeats`` calls of ``fn`` (after one warm-up call), ms; CUDA synchronised."""
    fn()
    _sync(device)
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        _sync(device)
        best = min(best, time.perf_counter() - t0)
    return best * 1e3


def frame_input(fr: dict, kind: str):
    """(x (1, C, H, W) float32, ok, order_traditional) of one frame: the network's input."""
    from unwrap.learned import fast_features as FF
    from unwrap.temporal import decode_pair

    lo, hi = (float(f) for f in fr["freqs"])
    valid = np.asarray(fr["valid"], bool) & np.isfinite(fr["phase_low"]) & np.isfinite(fr["phase_high"])
    prior, order_trad, valid = decode_pair(fr["method"], np.nan_to_num(fr["phase_low"]), np.nan_to_num(fr["phase_high"]),
                                           lo, hi, float(fr["width"]), valid)
    x, ok = FF.make_inputs(kind, fr["method"], prior, fr["phase_low"], fr["phase_high"], fr["m_low"], fr["m_high"],
                           order_trad, valid, (lo, hi))
    return x, ok, order_trad


def decode_orders(pred, x, ok, order_trad, f_hi: float):
    """(orders int64 (H, W), logits (K, H, W) float32) of a predictor on one input."""
    from unwrap.learned import fast_features as FF

    H, W = x.shape[-2:]
    xx = pred.prepare(x) if hasattr(pred, "prepare") else x
    z = pred.logits(xx)[..., :H, :W]
    order, _ = FF.decode(z, order_trad, ok, f_hi, pred.arch["kind"], int(pred.arch["max_correction"]))
    return order, z[0]


def _margin(z):
    """The logit margin between the two most probable classes (K, H, W) -> (H, W)."""
    s = np.sort(z, axis=0)
    return s[-1] - s[-2]


def training_rate(path, device: str, amp: bool, batch: int, repeats: int, crop: int = 128) -> float:
    """Samples/s of forward + backward + AdamW on ``batch`` random crops (float32 or bf16 autocast)."""
    import torch

    from unwrap.learned.checkpoint import build_model, read_checkpoint

    ck = read_checkpoint(path)
    net = build_model(ck["arch"]).to(device).train()
    opt = torch.optim.AdamW(net.parameters(), lr=1e-4)
    x = torch.randn(batch, ck["arch"]["in_channels"], crop, crop, device=device)

    def step():
        with torch.autocast(torch.device(device).type, dtype=torch.bfloat16, enabled=amp):
            loss = net(x).float().square().mean()
        loss.backward()
        opt.step()
        opt.zero_grad()

    return batch / (best_ms(step, repeats, device) / 1e3)


# ---------------------------------------------------------------- the measurement
def _machine(log) -> dict:
    import torch

    cuda = torch.cuda.is_available()
    machine = dict(cpu=platform.processor() or platform.machine(), cores=os.cpu_count(), torch=torch.__version__,
                   gpu=torch.cuda.get_device_name(0) if cuda else None, numpy=np.__version__)
    try:
        import onnxruntime as ort
        machine["onnxruntime"] = f"{ort.__version__} ({', '.join(ort.get_available_providers())})"
    except ImportError:
        pass
    log(f"machine: {machine}")
    return machine


def forward_rows(name, path, net, ck, repeats, log, skip=()) -> tuple[dict, dict]:
    """({row: ms} of one 640 x 480 frame's forward, {variant: predictor}) (module docstring)."""
    import torch

    from unwrap.learned.checkpoint import load_model
    from unwrap.learned.runtime import TorchPredictor, load_predictor

    C, H, W = int(ck["arch"]["in_channels"]), *SIZE
    x1, x8 = np.zeros((1, C, H, W), np.float32), np.zeros((8, C, H, W), np.float32)
    fw, all_threads = {}, torch.get_num_threads()
    cpu_pred = TorchPredictor(net, ck, channels_last=False, fold_norm=False)     # the plain network: the reference
    for threads in (2, all_threads):
        torch.set_num_threads(threads)
        fw[f"torch cpu, {threads} threads"] = best_ms(lambda: cpu_pred.logits(x1), repeats)
        log(f"{name}: forward torch cpu {threads} threads {fw[f'torch cpu, {threads} threads']:.1f} ms")
    torch.set_num_threads(2)
    onnx_pred = None
    if "onnx" not in skip:
        try:
            import tempfile

            from unwrap.learned.runtime import OnnxPredictor, export_onnx
            with tempfile.TemporaryDirectory() as td:
                op = OnnxPredictor(export_onnx((net, ck), Path(td) / "m.onnx"), threads=2, device="cpu")
                fw["onnxruntime cpu, 2 threads"] = best_ms(lambda: op.logits(x1), repeats)
                onnx_pred = op
                log(f"{name}: forward onnxruntime cpu 2 threads {fw['onnxruntime cpu, 2 threads']:.1f} ms")
        except Exception as exc:            # report, go on: the GPU rows matter more here
            log(f"{name}: onnxruntime row skipped ({type(exc).__name__}: {str(exc)[:200]})")
    variants = {"cpu fp32": cpu_pred}
    if "onnx" not in skip and onnx_pred is not None:       # its orders counted beside (the session outlives its file)
        variants["onnxruntime cpu"] = onnx_pred
    if "cpu-variants" not in skip:      # what load_predictor runs on the CPU: channels-last, BatchNorm folded
        variants["cpu fp32 channels-last folded"] = TorchPredictor(net, ck)
        fw["torch cpu channels-last folded, 2 threads"] = best_ms(
            lambda: variants["cpu fp32 channels-last folded"].logits(x1), repeats)
    if torch.cuda.is_available():
        torch.backends.cudnn.benchmark = True      # one frame size throughout: let cuDNN pick its kernels
        for prec in ("fp32", "fp16", "bf16"):
            variants[f"cuda {prec}"] = load_predictor(path, device="cuda", precision=prec)
        cl_net, _ = load_model(path, "cuda")
        variants["cuda fp32 channels-last"] = TorchPredictor(cl_net, ck, channels_last=True)
        variants["cuda bf16 channels-last"] = TorchPredictor(cl_net, ck, channels_last=True, precision="bf16")
        for v, pred in [(v, p) for v, p in variants.items() if v.startswith("cuda")]:
            fw[v] = best_ms(lambda: pred.logits(x1), repeats, "cuda")
            fw[v + ", batch 8 (per frame)"] = best_ms(lambda: pred.logits(x8), repeats, "cuda") / 8
            log(f"{name}: forward {v} {fw[v]:.2f} ms; batch 8 {fw[v + ', batch 8 (per frame)']:.2f} ms/frame")
    return fw, variants


def path_row(fr, variants, repeats) -> dict:
    """Whole learned path per frame (ms) of each precision beside the traditional decode; CUDA rows
    with the pixels whose order differs from the CPU path's."""
    from unwrap.learned.infer import unwrap_learned
    from unwrap.temporal import decode_pair

    lo, hi = (float(f) for f in fr["freqs"])
    args = (fr["method"], fr["phase_low"], fr["phase_high"], fr["m_low"], fr["m_high"], fr["valid"], (lo, hi))
    valid = np.asarray(fr["valid"], bool)
    row = dict(frame=fr["name"], pixels=int(valid.sum()), size=list(valid.shape))
    row["traditional ms"] = best_ms(lambda: decode_pair(fr["method"], np.nan_to_num(fr["phase_low"]),
                                                        np.nan_to_num(fr["phase_high"]), lo, hi, float(fr["width"]),
                                                        valid), repeats)
    orders = {}
    for v in ("cpu fp32", "cpu fp32 channels-last folded", "cuda fp32", "cuda fp16", "cuda bf16"):
        if v in variants:
            run = lambda: unwrap_learned(*args, width=float(fr["width"]), model=variants[v],  # noqa: E731
                                         on_outside="ignore")
            row[f"whole path {v} ms"] = best_ms(run, repeats, "cuda" if v.startswith("cuda") else "cpu")
            orders[v] = run().order
    for v, o in list(orders.items())[1:]:      # CUDA, MF: features and decode on the device too; CPU: NHWC features
        row[f"whole path {v}: orders differing"] = int((o != orders["cpu fp32"]).sum())
    return row


def orders_row(fr, variants, kind) -> dict:
    """Each variant's orders against torch fp32 on the CPU on every valid pixel of ``fr`` (the forward
    alone: the same numpy inputs), the CPU's logit margin where they differ, error % vs the reference."""
    hi = float(fr["freqs"][1])
    x, ok, order_trad = frame_input(fr, kind)
    base, z = decode_orders(variants["cpu fp32"], x, ok, order_trad, hi)
    margin = _margin(z)
    ref = np.asarray(fr["ref"])
    scored = ok & (ref >= 0)
    err = lambda o: 100.0 * float((o[scored] != ref[scored]).mean()) if scored.any() else None  # noqa: E731
    row = dict(frame=fr["name"], valid=int(ok.sum()), scored=int(scored.sum()),
               margin_median=float(np.median(margin[ok])) if ok.any() else None)
    row["error % cpu fp32"] = err(base)
    for v, pred in list(variants.items())[1:]:
        o, _ = decode_orders(pred, x, ok, order_trad, hi)
        diff = ok & (o != base)
        row[f"{v}: differing"] = int(diff.sum())
        row[f"{v}: max margin there"] = float(margin[diff].max()) if diff.any() else None
        row[f"error % {v}"] = err(o)
    return row


def measure(models: dict, frames: list, repeats: int, log=print, skip=()) -> dict:
    """{"machine": ..., "models": {name: {"forward": {...}, "path": [...], "orders": [...], "train": {...}}}}."""
    import torch

    from unwrap.learned.checkpoint import load_model

    cuda = torch.cuda.is_available()
    res = {"machine": _machine(log), "models": {}}
    for name, path in models.items():
        net, ck = load_model(path, "cpu")
        fw, variants = forward_rows(name, path, net, ck, repeats, log, skip)
        r = res["models"][name] = {"forward": fw, "path": [], "orders": [], "train": {}}
        for fr in frames:
            r["path"].append(path_row(fr, variants, repeats))
            log(f"{name}: path {r['path'][-1]}")
            r["orders"].append(orders_row(fr, variants, ck["arch"]["kind"]))
            log(f"{name}: orders {r['orders'][-1]}")
        runs = [] if "train" in skip else [("cpu", False, 8)] + ([(d, a, b) for d, a in (("cuda", False), ("cuda", True))
                                                                   for b in (8, 64)] if cuda else [])
        for dev, amp, batch in runs:
            key = f"{dev}{' bf16 AMP' if amp else ' fp32'}, batch {batch}"
            r["train"][key] = training_rate(path, dev, amp, batch, max(2, repeats // 2))
            log(f"{name}: train {key} {r['train'][key]:.1f} samples/s")
    return res


def table(res: dict) -> str:
    m = res["machine"]
    lines = [f"machine: {m['cpu']}, {m['cores']} cores; GPU: {m['gpu'] or 'none (CPU rows only)'}; torch "
             f"{m['torch']}; onnxruntime {m.get('onnxruntime', 'absent')}; numpy {m['numpy']}", ""]
    for name, r in res["models"].items():
        base = r["forward"].get("torch cpu, 2 threads")
        lines += [f"### {name}: forward, one 640x480 frame", "", "| variant | ms | x torch cpu 2 threads |",
                  "|---|---:|---:|"]
        for k, v in r["forward"].items():
            lines.append(f"| {k} | {v:.2f} | {v / base:.3f} |")
        lines += ["", f"### {name}: whole learned path per frame (ms) beside the traditional decode", ""]
        if r["path"]:
            cols = [k for k in r["path"][0] if k.endswith(" ms") or k.endswith("differing")]
            lines += ["| frame | pixels | " + " | ".join(cols) + " |", "|---|---:|" + "---:|" * len(cols)]
            for row in r["path"]:
                lines.append(f"| {row['frame']} | {row['pixels']} | " + " | ".join(
                    f"{row[c]:.1f}" if isinstance(row[c], float) else str(row[c]) for c in cols) + " |")
        lines += ["", f"### {name}: orders against torch fp32 on the CPU (every valid pixel)", ""]
        if r["orders"]:
            cols = [k for k in r["orders"][0] if k not in ("frame",)]
            lines += ["| frame | " + " | ".join(cols) + " |", "|---|" + "---:|" * len(cols)]
            for row in r["orders"]:
                lines.append(f"| {row['frame']} | " + " | ".join(
                    "-" if row[c] is None else (f"{row[c]:.4g}" if isinstance(row[c], float) else str(row[c]))
                    for c in cols) + " |")
        lines += ["", f"### {name}: training samples/s (128x128 crops)", "", "| device | samples/s |", "|---|---:|"]
        for k, v in r["train"].items():
            lines.append(f"| {k} | {v:.1f} |")
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--save-frames", default=None, metavar="NPZ", help="write the real / twin frames and stop")
    p.add_argument("--test", nargs="*", default=[], help="with --save-frames: twin dataset files to take frames from")
    p.add_argument("--work", default=None, help="with --save-frames: where the skull's export is cached "
                   "(default: beside the frames file)")
    p.add_argument("--frames", default=None, metavar="NPZ", help="frames for the path and order rows (default: the ramp)")
    p.add_argument("--model", action="append", default=[], metavar="NAME=PATH",
                   help="checkpoints to measure (default: shipped=the shipped model)")
    p.add_argument("--repeats", type=int, default=10)
    p.add_argument("--skip", nargs="*", default=[], choices=["onnx", "train", "cpu-variants"],
                   help="rows to leave out (cpu-variants: the channels-last / folded CPU forward the path runs)")
    p.add_argument("--json", default=None, help="also write the results as JSON")
    p.add_argument("--quick", action="store_true", help="2 repeats, the ramp frame only")
    args = p.parse_args(argv)
    if args.save_frames:
        names = save_frames(args.save_frames, args.test, args.work)
        print(f"{len(names)} frames -> {args.save_frames}: {', '.join(names)}")
        return 0
    from unwrap.learned.runtime import shipped_model_path

    models = dict(m.split("=", 1) for m in args.model) or {"shipped": str(shipped_model_path())}
    frames = [ramp_frame()] + (load_frames(args.frames) if args.frames and not args.quick else [])
    if args.quick:
        args.repeats = 2
    res = measure(models, frames, args.repeats, log=lambda s: print(s, file=sys.stderr, flush=True), skip=args.skip)
    print(table(res))
    if args.json:
        from unwrap.safe_output import write_text
        write_text(Path(args.json), json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
