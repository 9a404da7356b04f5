"""What the learned unwrapping costs in time, beside the traditional paths it replaces.

Run: ``python -m bench.learned_speed [--model PATH] [--repeats N] [--threads T]`` (``--quick``: 2 repeats).

One orientation of a 640 x 480 frame, MF (1, 48), 12 steps (`experiments.learned_evaluation.speed_table`):
the traditional TPU from frames (fused kernel: wrapped phases + MF in one pass) and from wrapped
phases (the prior and its rounding), the filtered baseline (15 x 15 plane fit of the unit phase),
the network alone as the path runs it (on the CPU: channels-last, BatchNorm folded, its input in
that layout) and the whole learned path (prior + input features + network + decode), and their
ratio (issue 22's goals: forward <= 40 ms on 2 cores, whole path <= 2x the forward). Every
time is the minimum over ``repeats`` calls in the same process, so a shared machine's load hits
all rows alike; the ratios to the traditional rows are what to read. Training throughput
(samples/s of 128 x 128 crops, forward + backward + AdamW step, batch 8) is measured the same way.
"""
from __future__ import annotations

import argparse
import time


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


def main(argv=None) -> int:
    import torch

    from experiments.learned_evaluation import speed_table
    from unwrap.learned.infer import shipped_model_path

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default=None, help="checkpoint (default: the shipped model)")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--threads", type=int, default=0, help="torch threads (default: torch's)")
    p.add_argument("--quick", action="store_true", help="2 repeats (checks that the benchmark runs)")
    args = p.parse_args(argv)
    if args.quick:
        args.repeats = 2
    if args.threads:
        torch.set_num_threads(args.threads)
    model = args.model or shipped_model_path()
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
