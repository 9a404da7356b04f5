"""Checkpoints: atomic writes, and loading that refuses what it cannot use, saying why.

A checkpoint is a ``torch.save`` dict of plain types and tensors (loaded with
``weights_only=True``: no code runs when a file is read):

- ``format`` (:data:`FORMAT`), ``format_version``;
- ``arch``: the network's constructor arguments and model kind (``kind``, ``width``, ``depth``,
  ``max_width``, ``max_correction``, ``in_channels``, ``out_channels``; ``conv`` only where not
  "full", ``norm`` only where not "group", ``stem`` only where not "shuffle");
- ``model``: the state dict; ``meta``: what it was trained on (methods, frequency pairs, ...);
- training checkpoints add ``optimizer``, ``scheduler``, ``step``, ``epoch``, ``batch_in_epoch``,
  ``rng`` (torch, numpy, python, CUDA states), ``config`` and ``best``.

Writes go to a temporary file in the same folder, fsync'ed, then renamed over the target
(``os.replace`` is atomic on POSIX): a run killed mid-write leaves the previous checkpoint intact.
"""
from __future__ import annotations

import errno
from pathlib import Path

import torch

from .errors import CheckpointError
from .features import input_channels, output_channels
from .network import FringeUNet

FORMAT = "sltwin-unwrap-model"
FORMAT_VERSION = 1
ARCH_KEYS = ("kind", "width", "depth", "max_width", "max_correction", "in_channels", "out_channels")
#: The optional ``arch`` keys and the value their absence means (the shipped model's).
ARCH_OPTIONAL = {"conv": "full", "norm": "group", "stem": "shuffle"}


def arch_from_config(model_cfg) -> dict:
    """The ``arch`` dict of a model config section (``[model]``, a ``config.ModelConfig``)."""
    kind = model_cfg.kind
    K = int(model_cfg.max_correction)
    arch = {"kind": kind, "width": int(model_cfg.width), "depth": int(model_cfg.depth),
            "max_width": int(model_cfg.max_width), "max_correction": K,
            "in_channels": input_channels(kind), "out_channels": output_channels(kind, K)}
    for k, default in ARCH_OPTIONAL.items():      # only when not the default: older checkpoints' arch stays as it was
        if getattr(model_cfg, k, default) != default:
            arch[k] = getattr(model_cfg, k)
    return arch


def build_model(arch: dict) -> FringeUNet:
    """The network of an ``arch`` dict (raises :class:`CheckpointError` for an unknown layout)."""
    missing = [k for k in ARCH_KEYS if k not in arch]
    if missing:
        raise CheckpointError(f"model architecture lacks {missing} (keys expected: {ARCH_KEYS})")
    kind = arch["kind"]
    try:
        want_in, want_out = input_channels(kind), output_channels(kind, arch["max_correction"])
    except Exception as exc:
        raise CheckpointError(f"model architecture: {exc}") from None
    if (arch["in_channels"], arch["out_channels"]) != (want_in, want_out):
        raise CheckpointError(
            f"model architecture: a {kind!r} model has {want_in} inputs and {want_out} outputs in this "
            f"version, the checkpoint says {arch['in_channels']} and {arch['out_channels']}")
    try:
        net = FringeUNet(want_in, want_out, width=arch["width"], depth=arch["depth"], max_width=arch["max_width"],
                         **{k: arch.get(k, default) for k, default in ARCH_OPTIONAL.items()})
    except ValueError as exc:
        raise CheckpointError(f"model architecture: {exc}") from None
    if kind == "physics":
        # start from "keep the traditional order" (correction 0 at ~95 %): most pixels are right, and
        # the network then spends its training on the ones that are not
        with torch.no_grad():
            net.refine[-1].bias.zero_()
            net.refine[-1].bias[arch["max_correction"]] = 3.0
    return net


def save_atomic(obj: dict, path) -> Path:
    """``torch.save(obj)`` to ``path`` atomically (temporary file + fsync + rename)."""
    from ..safe_output import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp:
        try:
            with open(tmp, "wb") as fh:
                torch.save(obj, fh)
        except RuntimeError as exc:   # torch reports a failed write (a full disk) as a RuntimeError
            text = str(exc)
            if "write" not in text.lower() and "enforce fail" not in text:
                raise                  # not the file: an object that cannot be saved
            raise OSError(errno.EIO, f"could not write the checkpoint ({text.splitlines()[0][:200]}); the previous "
                          f"{path.name}, if any, is intact") from exc
    return path


def read_checkpoint(path) -> dict:
    """The checkpoint dict of ``path``, checked for format; :class:`CheckpointError` otherwise."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint not found: {path}")
    try:
        ck = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:   # zip / pickle / EOF errors of a truncated or foreign file
        raise CheckpointError(f"{path}: not a readable checkpoint (corrupt or not a torch file: "
                              f"{type(exc).__name__}: {str(exc)[:200]})") from None
    if not isinstance(ck, dict) or ck.get("format") != FORMAT:
        got = ck.get("format") if isinstance(ck, dict) else type(ck).__name__
        raise CheckpointError(f"{path}: not an sltwin unwrapping model (format {got!r}, expected {FORMAT!r})")
    if int(ck.get("format_version", -1)) != FORMAT_VERSION:
        raise CheckpointError(f"{path}: checkpoint format version {ck.get('format_version')}, this code reads "
                              f"version {FORMAT_VERSION}")
    for key in ("arch", "model", "meta"):
        if key not in ck:
            raise CheckpointError(f"{path}: checkpoint lacks {key!r}")
    return ck


def load_model(path_or_ck, device="cpu"):
    """(model in eval mode, checkpoint dict) from a checkpoint file or an already-read dict.

    Refuses (:class:`CheckpointError`) a file of another format or architecture, naming the
    parameters that do not fit.
    """
    ck = read_checkpoint(path_or_ck) if not isinstance(path_or_ck, dict) else path_or_ck
    where = path_or_ck if not isinstance(path_or_ck, dict) else "checkpoint"
    model = build_model(ck["arch"])
    own = model.state_dict()
    theirs = ck["model"]
    missing = [k for k in own if k not in theirs]
    extra = [k for k in theirs if k not in own]
    shape = [f"{k}: {tuple(theirs[k].shape)} vs {tuple(own[k].shape)}" for k in own
             if k in theirs and tuple(theirs[k].shape) != tuple(own[k].shape)]
    if missing or extra or shape:
        raise CheckpointError(
            f"{where}: weights do not fit the architecture {ck['arch']} (another architecture or a "
            f"damaged file): missing {missing[:4]}{'...' if len(missing) > 4 else ''}, unexpected "
            f"{extra[:4]}{'...' if len(extra) > 4 else ''}, shape mismatches {shape[:3]}")
    bad = [k for k, v in theirs.items() if v.is_floating_point() and not torch.isfinite(v).all()]
    if bad:
        raise CheckpointError(f"{where}: non-finite weights in {bad[:4]} (a diverged or damaged model)")
    model.load_state_dict(theirs)
    return model.to(device).eval(), ck


def export_model(ck: dict, path) -> Path:
    """Write the inference-only part of a training checkpoint (arch, weights, meta): the small
    file that ships (no optimiser state)."""
    slim = {"format": FORMAT, "format_version": FORMAT_VERSION, "arch": ck["arch"],
            "model": {k: v.detach().cpu().clone() for k, v in ck["model"].items()}, "meta": ck["meta"]}
    return save_atomic(slim, path)
