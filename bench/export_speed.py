"""Speed and size of the dataset export and of its reader: ``python -m bench.export_speed
[--samples 8] [--config synth/data/export_train.toml]``.

1. Export ``--samples`` samples of the config (default: the training set's, 640x480, mesh scenes,
   v + h, f = 1, 47, 48 at 12 steps = 72 images a sample, global illumination, defocus, noise):
   samples/s and the share of each stage (geometry, patterns, noise, phase, labels, write).
   The renderer's own time for the same images is geometry + patterns + noise; the goal is that
   phase + write add at most 30 % to it. The label check (a second, clean render and traditional
   TPU on both noise-free renders) is reported apart.
2. Codecs on the exported arrays (one chunk per sample and frequency, shuffle): compression
   ratio, write and read MB/s of uncompressed bytes, and the read time of one reader item.
3. The reader: items/s of ``FringeOrderDataset`` (MF 1 -> 48, 256 x 256 random crops, flips) through
   a DataLoader with 0 and 2 workers, against the training step of a small U-Net (4 levels, 16-128
   channels, 5 input maps, batch 8 of 256 x 256, Adam) on the same cores: the goal is that the
   reader feeds at least 5x faster than the network trains.

The machine's 2 cores may be shared with other jobs: the table says the load average at start
and end; times are minima (codecs, U-Net) or totals (export) as stated.
"""
from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]


def _load() -> str:
    return " / ".join(f"{v:.1f}" for v in os.getloadavg())


def export_part(config, n: int, out: Path) -> dict:
    from synth.export.config import load_config
    from synth.export.dataset import export_dataset

    cfg = load_config(config)
    cfg.samples = n
    t0 = time.perf_counter()
    s = export_dataset(cfg, out, progress=False)
    s["wall"] = time.perf_counter() - t0
    return s


def codec_table(path: Path, codecs=("gzip-1", "gzip-4", "lzf", "none")) -> list:
    import h5py

    from synth.export.writer import _filters

    with h5py.File(path, "r") as h5:
        names = [n for n in ("v/phase", "v/modulation", "v/flags", "v/order", "v/coordinate", "h/phase", "h/modulation",
                             "h/flags", "h/order", "h/coordinate", "masks") if n in h5]
        data = {n: h5[n][...] for n in names}
    raw = sum(a.nbytes for a in data.values())
    rows = []
    tmp = Path(tempfile.mkdtemp(prefix="codec_"))
    for codec in codecs:
        p = tmp / f"{codec}.h5"
        best_w = best_r = best_item = float("inf")
        for _ in range(3):
            t = time.perf_counter()
            with h5py.File(p, "w") as h5:
                for n, a in data.items():
                    h5.create_dataset(n, data=a, chunks=(1,) * (a.ndim - 2) + a.shape[-2:], **_filters(codec))
            best_w = min(best_w, time.perf_counter() - t)
            t = time.perf_counter()
            with h5py.File(p, "r") as h5:
                for n in names:
                    h5[n][...]
            best_r = min(best_r, time.perf_counter() - t)
            t = time.perf_counter()
            with h5py.File(p, "r") as h5:  # what one MF item reads: 2 frequencies x 3 maps + coordinate + masks
                for n in ("v/phase", "v/modulation", "v/flags"):
                    h5[n][0, 0]
                    h5[n][0, -1]
                h5["v/coordinate"][0]
                h5["masks"][0]
            best_item = min(best_item, time.perf_counter() - t)
        rows.append((codec, raw / p.stat().st_size, raw / best_w / 1e6, raw / best_r / 1e6, 1e3 * best_item,
                     p.stat().st_size / len(data["masks"])))
    shutil.rmtree(tmp)
    return rows


class SmallUNet(torch.nn.Module):
    """4 levels (16, 32, 64, 128 channels), two 3x3 convolutions per level, for the timing only."""

    def __init__(self, cin: int = 5, base: int = 16):
        super().__init__()
        c = [base, 2 * base, 4 * base, 8 * base]

        def block(a, b):
            return torch.nn.Sequential(torch.nn.Conv2d(a, b, 3, padding=1), torch.nn.ReLU(inplace=True),
                                       torch.nn.Conv2d(b, b, 3, padding=1), torch.nn.ReLU(inplace=True))
        self.down = torch.nn.ModuleList([block(cin, c[0]), block(c[0], c[1]), block(c[1], c[2]), block(c[2], c[3])])
        self.up = torch.nn.ModuleList([torch.nn.ConvTranspose2d(c[i + 1], c[i], 2, stride=2) for i in range(3)])
        self.dec = torch.nn.ModuleList([block(2 * c[i], c[i]) for i in range(3)])
        self.head = torch.nn.Conv2d(c[0], 1, 1)

    def forward(self, x):
        skips = []
        for i, d in enumerate(self.down):
            x = d(x)
            if i < 3:
                skips.append(x)
                x = torch.nn.functional.max_pool2d(x, 2)
        for i in reversed(range(3)):
            x = self.dec[i](torch.cat([self.up[i](x), skips[i]], 1))
        return self.head(x)


def unet_samples_per_s(batch: int = 8, size: int = 256, steps: int = 4) -> float:
    net = SmallUNet()
    opt = torch.optim.Adam(net.parameters(), 1e-3)
    x = torch.randn(batch, 5, size, size)
    y = torch.randn(batch, 1, size, size)
    best = float("inf")
    for i in range(steps + 1):
        t = time.perf_counter()
        opt.zero_grad()
        loss = torch.nn.functional.mse_loss(net(x), y)
        loss.backward()
        opt.step()
        if i:
            best = min(best, time.perf_counter() - t)
    return batch / best


def reader_items_per_s(path: Path, workers: int, n_batches: int = 6, batch: int = 8) -> float:
    from unwrap.dataset import FringeOrderDataset

    ds = FringeOrderDataset(path, method="mf", frequencies=(1, 48), crop=(256, 256), flip=True, seed=0)
    idx = np.arange(n_batches * batch) % len(ds)
    sub = torch.utils.data.Subset(ds, idx.tolist())
    loader = torch.utils.data.DataLoader(sub, batch_size=batch, num_workers=workers,
                                         persistent_workers=False)
    t = time.perf_counter()
    n = 0
    for b in loader:
        n += b["prior"].shape[0]
    return n / (time.perf_counter() - t)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(REPO / "synth" / "data" / "export_train.toml"))
    ap.add_argument("--samples", type=int, default=8)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="2 samples (make bench): a smoke run, not for quoting")
    args = ap.parse_args(argv)
    if args.quick:
        args.samples = 2
    torch.set_num_threads(args.threads)
    print(f"load average at start (1/5/15 min): {_load()}  (2 cores, shared with other engineers' jobs)")
    work = Path(tempfile.mkdtemp(prefix="bench_export_"))
    try:
        export_part(args.config, 1, work / "warm.h5")  # kernels loaded, meshes read, rays cached
        s = export_part(args.config, args.samples, work / "bench.h5")
        st = s["stage_seconds"]
        total = sum(st.values())
        render = st["geometry"] + st["patterns"] + st["noise"]
        print(f"\n## Export ({args.samples} samples, {Path(args.config).name}, 640x480)\n")
        print(f"| samples/s | s/sample | renderer (geometry + patterns + noise) s/sample | phase + write s/sample "
              f"| overhead vs renderer | label check s/sample |")
        print("|---|---|---|---|---|---|")
        n = args.samples
        print(f"| {n / s['wall']:.3f} | {s['wall'] / n:.2f} | {render / n:.3f} | {(st['phase'] + st['write']) / n:.3f} "
              f"| {100 * (st['phase'] + st['write']) / render:.0f} % | {st['labels'] / n:.3f} |")
        print("\nstage shares: " + ", ".join(f"{k} {100 * v / total:.0f} %" for k, v in st.items()))
        print(f"\nbytes/sample {s['bytes_per_sample'] / 1e6:.2f} MB, compression ratio {s['compression_ratio']:.2f} "
              f"(codec {os.path.basename(args.config)}: see the file's attribute), uncompressed "
              f"{s['raw_bytes'] / n / 1e6:.2f} MB/sample")
        print("\n## Codecs (the exported arrays, one chunk per sample and frequency, shuffle; best of 3)\n")
        print("| codec | ratio | write MB/s | read MB/s | one MF item read ms | MB/sample |")
        print("|---|---|---|---|---|---|")
        for c, ratio, w, r, item, per in codec_table(work / "bench.h5"):
            print(f"| {c} | {ratio:.2f} | {w:.0f} | {r:.0f} | {item:.1f} | {per / 1e6:.2f} |")
        print("\n## Reader vs training (MF 1 -> 48, 256x256 crops + flips, batch 8)\n")
        unet = unet_samples_per_s()
        print("| reader workers | items/s | x U-Net training samples/s |")
        print("|---|---|---|")
        for w in (0, 2):
            r = reader_items_per_s(work / "bench.h5", w)
            print(f"| {w} | {r:.1f} | {r / unet:.1f}x |")
        print(f"\nsmall U-Net (4 levels, 16-128 channels) training: {unet:.2f} samples/s "
              f"({args.threads} threads)")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(f"\nload average at end: {_load()}")


if __name__ == "__main__":
    main()
