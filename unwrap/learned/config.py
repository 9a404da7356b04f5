"""Training configuration: TOML file + ``section.key=value`` overrides -> a checked, resolved dict.

Every key has a default (:data:`DEFAULTS`); a key that is not one of them is refused naming it
(a typo never silently falls back to a default). Values are checked against the default's type
(an int is accepted where a float is expected) and, where it matters, their range.

SYNOPSIS

    >>> from unwrap.learned.config import resolve_config
    >>> cfg = resolve_config(None, ["optim.steps=5", "model.width=8", "data.synthetic_samples=16"])
    >>> cfg["optim"]["steps"], cfg["model"]["width"], cfg["model"]["kind"]
    (5, 8, 'physics')
    >>> resolve_config(None, ["optim.stpes=5"])
    Traceback (most recent call last):
    ...
    unwrap.learned.errors.ConfigError: unknown key 'optim.stpes' (overrides); [optim] has: batch_size, grad_clip, lr, name, schedule, steps, warmup_steps, weight_decay
"""
from __future__ import annotations

import copy
import tomllib
from pathlib import Path

import tomli_w

from .errors import ConfigError
from .features import KINDS
from .losses import WEIGHTINGS

DEFAULTS: dict = {
    "data": {
        "train": [],                  # HDF5 dataset files (unwrap.dataset); empty: the synthetic set
        "synthetic_samples": 0,       # > 0: train on this many in-memory synthetic scenes instead
        "synthetic_size": [96, 128],  # (H, W) of a synthetic scene
        "methods": ["mf", "mw", "nt"],
        "mf_frequencies": [1.0, 48.0],
        "mw_frequencies": [47.0, 48.0],
        "nt_frequencies": [47.0, 48.0],
        "orientations": ["v", "h"],
        "crop": [128, 128],           # training window (H, W); [] for full frames
        "flip": True,                 # random flips (augmentation)
        "val_fraction": 0.1,          # scenes held out for validation
        "val_samples": 8,             # at most this many validation scenes per (method, orientation)
        "workers": 0,                 # DataLoader worker processes
    },
    "model": {"kind": "physics", "width": 16, "depth": 3, "max_width": 64, "max_correction": 2},
    "loss": {"mse": 1.0, "fourier": 0.1, "fourier_weighting": "focal", "fourier_alpha": 1.0, "ce": 0.0},
    "optim": {"name": "adamw", "lr": 2e-3, "weight_decay": 1e-4, "batch_size": 8, "steps": 2000, "warmup_steps": 50,
              "schedule": "cosine", "grad_clip": 1.0},
    "run": {"seed": 0, "deterministic": False, "device": "auto", "amp": True, "log_every": 10,
            "val_every": 200, "checkpoint_every": 100, "threads": 0},
}

_POSITIVE_INT = {"data.synthetic_samples": 0, "data.val_samples": 1, "data.workers": 0, "model.width": 1,
                 "model.depth": 1, "model.max_width": 1, "model.max_correction": 1, "optim.batch_size": 1,
                 "optim.steps": 1, "optim.warmup_steps": 0, "run.log_every": 1, "run.val_every": 1,
                 "run.checkpoint_every": 1, "run.threads": 0}
_CHOICES = {"optim.name": ("adamw", "sgd"), "model.kind": KINDS, "loss.fourier_weighting": WEIGHTINGS, "optim.schedule": ("cosine", "constant"),
            "run.device": ("auto", "cpu", "cuda")}


def _type_ok(value, default) -> bool:
    if isinstance(default, bool):
        return isinstance(value, bool)
    if isinstance(default, int):
        return isinstance(value, int) and not isinstance(value, bool)
    if isinstance(default, float):
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if isinstance(default, list):
        return isinstance(value, list)
    return isinstance(value, type(default))


def _merge(cfg: dict, tree: dict, where: str):
    for section, body in tree.items():
        if section not in DEFAULTS:
            raise ConfigError(f"unknown section [{section}] ({where}); sections: {', '.join(DEFAULTS)}")
        if not isinstance(body, dict):
            raise ConfigError(f"[{section}] ({where}) must be a table of keys, got {body!r}")
        for key, value in body.items():
            if key not in DEFAULTS[section]:
                raise ConfigError(f"unknown key '{section}.{key}' ({where}); [{section}] has: "
                                  f"{', '.join(sorted(DEFAULTS[section]))}")
            default = DEFAULTS[section][key]
            if not _type_ok(value, default):
                raise ConfigError(f"{section}.{key} = {value!r} ({where}): expected a "
                                  f"{type(default).__name__} like the default {default!r}")
            cfg[section][key] = float(value) if isinstance(default, float) else value


def _parse_override(text: str) -> dict:
    if "=" not in text or "." not in text.split("=", 1)[0]:
        raise ConfigError(f"override {text!r}: expected section.key=value, e.g. optim.lr=1e-3")
    name, raw = text.split("=", 1)
    section, key = name.strip().split(".", 1)
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()   # a bare word: a string
    return {section: {key: value}}


def _check(cfg: dict):
    for name, lo in _POSITIVE_INT.items():
        s, k = name.split(".")
        if cfg[s][k] < lo:
            raise ConfigError(f"{name} = {cfg[s][k]}: expected >= {lo}")
    for name, choices in _CHOICES.items():
        s, k = name.split(".")
        if cfg[s][k] not in choices:
            raise ConfigError(f"{name} = {cfg[s][k]!r}: expected one of {choices}")
    d = cfg["data"]
    if not 0.0 <= d["val_fraction"] < 1.0:
        raise ConfigError(f"data.val_fraction = {d['val_fraction']}: expected 0 <= value < 1")
    bad = [m for m in d["methods"] if m not in ("mf", "mw", "nt")]
    if bad or not d["methods"]:
        raise ConfigError(f"data.methods = {d['methods']}: expected a non-empty list of 'mf', 'mw', 'nt'")
    bad = [o for o in d["orientations"] if o not in ("v", "h")]
    if bad or not d["orientations"]:
        raise ConfigError(f"data.orientations = {d['orientations']}: expected a non-empty list of 'v', 'h'")
    for m in ("mf", "mw", "nt"):
        f = d[f"{m}_frequencies"]
        if len(f) != 2 or not all(isinstance(v, (int, float)) and v > 0 for v in f) or not f[1] > f[0]:
            raise ConfigError(f"data.{m}_frequencies = {f}: expected [low, high] with high > low > 0")
    if d["crop"] and (len(d["crop"]) != 2 or min(d["crop"]) < 16):
        raise ConfigError(f"data.crop = {d['crop']}: expected [] or [h, w] with h, w >= 16")
    if len(d["synthetic_size"]) != 2 or min(d["synthetic_size"]) < 16:
        raise ConfigError(f"data.synthetic_size = {d['synthetic_size']}: expected [h, w] >= 16")
    if not d["train"] and d["synthetic_samples"] == 0:
        raise ConfigError("no training data: set data.train (HDF5 files) or data.synthetic_samples > 0")
    o = cfg["optim"]
    if not (o["lr"] > 0 and o["weight_decay"] >= 0 and o["grad_clip"] >= 0):
        raise ConfigError(f"optim: lr {o['lr']} must be > 0, weight_decay and grad_clip >= 0")
    from .losses import LossWeights
    LossWeights(**cfg["loss"])


def resolve_config(path=None, overrides=()) -> dict:
    """The resolved config: defaults <- TOML file ``path`` (optional) <- ``overrides``.

    Raises :class:`ConfigError` naming an unknown key, a wrong type or an out-of-range value.
    """
    cfg = copy.deepcopy(DEFAULTS)
    if path is not None:
        p = Path(path)
        try:
            tree = tomllib.loads(p.read_text())
        except FileNotFoundError:
            raise ConfigError(f"config file not found: {p}") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{p}: not valid TOML ({exc})") from None
        _merge(cfg, tree, str(p))
    for text in overrides or ():
        _merge(cfg, _parse_override(text), "overrides")
    _check(cfg)
    return cfg


def to_toml(cfg: dict) -> str:
    """The resolved config as TOML text (what a run folder keeps as ``config.toml``)."""
    return tomli_w.dumps(cfg)
