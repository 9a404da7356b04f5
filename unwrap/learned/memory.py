"""Memory a training run will need, estimated before anything is allocated, and refused when it
cannot fit: a config may ask for ``model.max_correction = 1000000`` (two million output channels
per pixel) or ``model.depth = 12`` (every 128 px crop padded to 8192 px), which would take the
whole machine's memory (and the OOM killer) before the first step.

The estimate (bytes, float32): weights, gradients and the two AdamW moments (4 x the parameter
count, counted exactly on torch's ``meta`` device, which allocates nothing), plus the activations
one batch keeps for the backward pass (every block of :class:`unwrap.learned.network.FringeUNet`
at its resolution, about 6 tensors per block, the input padded to a multiple of ``2**(depth+1)``),
doubled for their gradients. It is a model of the allocation, good to a factor of about 2, which
is all the refusal needs: the absurd configs are orders of magnitude above any machine.

SYNOPSIS

    >>> from unwrap.learned.memory import training_bytes
    >>> arch = {"kind": "physics", "width": 16, "depth": 3, "max_width": 64, "max_correction": 2,
    ...         "in_channels": 7, "out_channels": 5}
    >>> 1e7 < training_bytes(arch, batch=8, crop=(128, 128)) < 2e9
    True
"""
from __future__ import annotations

import os

from .errors import ConfigError

#: The share of the available memory a run may plan to use.
SHARE = 0.8


def _parameters(arch: dict) -> int:
    import torch

    from .checkpoint import ARCH_OPTIONAL
    from .network import FringeUNet

    with torch.device("meta"):          # conv / norm / stem as the model is built (a separable one has ~7x fewer)
        net = FringeUNet(arch["in_channels"], arch["out_channels"], width=arch["width"], depth=arch["depth"],
                         max_width=arch["max_width"], **{k: arch.get(k, d) for k, d in ARCH_OPTIONAL.items()})
    return sum(p.numel() for p in net.parameters())


def _activation_floats(arch: dict, crop) -> int:
    """Floats one sample keeps for the backward pass (module docstring)."""
    m = 2 ** (int(arch["depth"]) + 1)
    H, W = (-(-int(s) // m) * m for s in crop)
    w, depth = int(arch["width"]), int(arch["depth"])
    chans = [min(w * 2 ** i, int(arch["max_width"])) for i in range(depth + 1)]
    n = 0
    for i, c in enumerate(chans):                       # encoder, decoder (same sizes), at half resolution / 2**i
        px = (H // 2 >> i) * (W // 2 >> i)
        n += 6 * c * px * (2 if i < depth else 4)       # the bottleneck has two dilated blocks
    full = H * W
    n += full * (arch["in_channels"] * 2 + 3 * w + 2 * arch["out_channels"])   # input, shuffle, refine, output
    return n


def training_bytes(arch: dict, batch: int, crop) -> int:
    """Estimated bytes of training ``arch`` on batches of ``batch`` crops of ``crop`` (H, W) px."""
    return 4 * (4 * _parameters(arch) + 2 * int(batch) * _activation_floats(arch, crop))


def available_bytes() -> int:
    """Memory available to a new allocation (``MemAvailable`` of /proc/meminfo, else the physical
    memory)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def check_training_memory(cfg, arch: dict, crop, available: int | None = None) -> int:
    """Refuse (:class:`ConfigError`) a run whose estimate exceeds :data:`SHARE` of ``available``
    (default :func:`available_bytes`), naming the estimate and the key that makes it large (the
    one whose default would shrink it most). Returns the estimate (bytes)."""
    from .config import TrainConfig

    defaults = TrainConfig()
    batch = int(cfg.optim.batch_size)
    need = training_bytes(arch, batch, crop)
    available = available_bytes() if available is None else int(available)
    if need <= SHARE * available:
        return need
    smaller = {}
    for key in ("width", "depth", "max_width", "max_correction"):
        default = getattr(defaults.model, key)
        if arch[key] > default:
            trial = dict(arch, **{key: default})
            if key == "max_correction":
                trial["out_channels"] = 2 * default + 1 if arch["kind"] == "physics" else arch["out_channels"]
            smaller[f"model.{key} = {arch[key]}"] = training_bytes(trial, batch, crop)
    if batch > defaults.optim.batch_size:
        smaller[f"optim.batch_size = {batch}"] = training_bytes(arch, defaults.optim.batch_size, crop)
    culprit = min(smaller, key=smaller.get) if smaller else f"data.crop = {list(crop)}"
    raise ConfigError(f"{culprit}: training would need about {need / 1e9:.3g} GB (weights, optimiser state and one "
                      f"batch of {batch} x {crop[0]}x{crop[1]} px), this machine has {available / 1e9:.3g} GB "
                      f"available; lower it (model {arch['width']}/{arch['depth']}/{arch['max_width']}/"
                      f"{arch['max_correction']} = width/depth/max_width/max_correction)")


def training_crop(cfg) -> tuple:
    """(H, W) px of one training input: ``data.crop``, else the synthetic size, else the camera
    size of the first training file (full frames)."""
    d = cfg.data
    if d.crop:
        return tuple(int(v) for v in d.crop)
    if not d.train:
        return tuple(int(v) for v in d.synthetic_size)
    import h5py

    try:
        with h5py.File(d.train[0], "r") as h5:
            W, H = (int(v) for v in h5.attrs["camera_size"])
    except (OSError, KeyError, TypeError, ValueError):
        return (128, 128)   # the reader names an unreadable file itself
    return H, W
