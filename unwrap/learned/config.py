"""Training configuration: TOML file + ``section.key=value`` overrides -> a checked, frozen
:class:`TrainConfig` (one dataclass per section).

Every key has a default (the dataclasses' fields); a key that is not one of them is refused naming
it and the closest known key (a typo never silently falls back to a default). Values are checked
against the field's type by the one strict reader (:mod:`unwrap.strict`; an int is accepted where
a float is expected, not a float where an int is) and, where it matters, their range.

SYNOPSIS

    >>> from unwrap.learned.config import resolve_config
    >>> cfg = resolve_config(None, ["optim.steps=5", "model.width=8", "data.synthetic_samples=16"])
    >>> cfg.optim.steps, cfg.model.width, cfg.model.kind
    (5, 8, 'physics')
    >>> resolve_config(None, ["optim.stpes=5"])
    Traceback (most recent call last):
    ...
    unwrap.learned.errors.ConfigError: overrides: unknown key 'optim.stpes' (did you mean 'optim.steps'?); [optim] has: batch_size, grad_clip, lr, name, schedule, steps, warmup_steps, weight_decay
    >>> resolve_config(None, ["optim.steps=4.0"])
    Traceback (most recent call last):
    ...
    unwrap.learned.errors.ConfigError: overrides: optim.steps = 4.0: expected an integer, got a float
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import tomli_w

from ..methods import PAIR_METHODS
from ..strict import apply_overrides, check_table, from_table, read_toml, schema_of, to_table
from .errors import ConfigError
from .features import KINDS
from .losses import WEIGHTINGS, LossWeights
from .network import CONV_KINDS, NORM_KINDS, STEM_KINDS

@dataclass(frozen=True)
class DataConfig:
    """``[data]``: what the network trains on."""

    train: tuple[str, ...] = ()                      # HDF5 dataset files (unwrap.dataset); empty: the synthetic set
    synthetic_samples: int = 0                      # > 0: train on this many in-memory synthetic scenes instead
    synthetic_size: tuple[int, ...] = (96, 128)     # (H, W) of a synthetic scene
    methods: tuple[str, ...] = PAIR_METHODS
    mf_frequencies: tuple[float, ...] = (1.0, 48.0)
    mw_frequencies: tuple[float, ...] = (47.0, 48.0)
    nt_frequencies: tuple[float, ...] = (47.0, 48.0)
    orientations: tuple[str, ...] = ("v", "h")
    crop: tuple[int, ...] = (128, 128)              # training window (H, W); () for full frames
    flip: bool = True                               # random flips (augmentation)
    val_fraction: float = 0.1                       # scenes held out for validation
    val_files: tuple[str, ...] = ()                 # whole files (captures) held out for validation instead (fine-tuning)
    val_samples: int = 8                            # at most this many validation scenes per (method, orientation)
    split_files: tuple[str, ...] = ()               # with val_files: files split by scene as a from-scratch run splits data.train
    workers: int = 0                                # DataLoader worker processes

    def frequencies(self, method: str) -> tuple[float, float]:
        """The (low, high) frequency pair ``method`` trains on."""
        return tuple(float(f) for f in getattr(self, f"{method}_frequencies"))


@dataclass(frozen=True)
class ModelConfig:
    """``[model]``: the network (unwrap.learned.network)."""

    kind: str = "physics"
    width: int = 16
    depth: int = 3
    max_width: int = 64
    max_correction: int = 2
    conv: str = "full"                              # "separable": depthwise + pointwise (network.CONV_KINDS)
    norm: str = "group"                             # "batch" / "none": no frame-wide op at inference (network.NORM_KINDS)
    stem: str = "shuffle"                           # "strided": no pixel (un)shuffle in the graph (network.STEM_KINDS)
    init: str = ""                                  # fine-tune: start from this checkpoint's weights ("learned": shipped)


@dataclass(frozen=True)
class OptimConfig:
    """``[optim]``: optimiser and schedule (``grad_clip = inf``: no clipping)."""

    name: str = "adamw"
    lr: float = 2e-3
    weight_decay: float = 1e-4
    batch_size: int = 8
    steps: int = 2000
    warmup_steps: int = 50
    schedule: str = "cosine"
    grad_clip: float = 1.0


@dataclass(frozen=True)
class RunConfig:
    """``[run]``: seed, device and how often to log, validate and checkpoint."""

    seed: int = 0
    deterministic: bool = False
    device: str = "auto"
    amp: bool = True
    log_every: int = 10
    val_every: int = 200
    checkpoint_every: int = 100
    threads: int = 0
    val_score: str = "pooled"                       # best step by: "pooled" error rate, or "groups": geometric mean of per-group rates


@dataclass(frozen=True)
class TrainConfig:
    """The resolved training config: one frozen dataclass per TOML section."""

    data: DataConfig = field(default_factory=DataConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    loss: LossWeights = field(default_factory=lambda: LossWeights(fourier=0.1))   # [loss]
    optim: OptimConfig = field(default_factory=OptimConfig)
    run: RunConfig = field(default_factory=RunConfig)


_POSITIVE_INT = {"data.synthetic_samples": 0, "data.val_samples": 1, "data.workers": 0, "model.width": 1,
                 "model.depth": 1, "model.max_width": 1, "model.max_correction": 1, "optim.batch_size": 1,
                 "optim.steps": 1, "optim.warmup_steps": 0, "run.log_every": 1, "run.val_every": 1,
                 "run.checkpoint_every": 1, "run.threads": 0}
_CHOICES = {"optim.name": ("adamw", "sgd"), "model.kind": KINDS, "model.conv": CONV_KINDS, "model.norm": NORM_KINDS, "model.stem": STEM_KINDS, "loss.fourier_weighting": WEIGHTINGS, "optim.schedule": ("cosine", "constant"),
            "run.device": ("auto", "cpu", "cuda"), "run.val_score": ("pooled", "groups")}


#: Learning rate of a fine-tuning run (``model.init`` set) when neither the file nor an override
#: sets ``optim.lr``: a tenth of the default, so that a few hundred steps on a few real captures
#: adjust the shipped weights instead of overwriting what they learned from the twin.
FINETUNE_LR = 2e-4


def _check(cfg: TrainConfig):
    for name, lo in _POSITIVE_INT.items():
        s, k = name.split(".")
        if getattr(getattr(cfg, s), k) < lo:
            raise ConfigError(f"{name} = {getattr(getattr(cfg, s), k)}: expected >= {lo}")
    for name, choices in _CHOICES.items():
        s, k = name.split(".")
        if getattr(getattr(cfg, s), k) not in choices:
            raise ConfigError(f"{name} = {getattr(getattr(cfg, s), k)!r}: expected one of {choices}")
    d = cfg.data
    if not 0.0 <= d.val_fraction < 1.0:
        raise ConfigError(f"data.val_fraction = {d.val_fraction}: expected 0 <= value < 1")
    bad = [m for m in d.methods if m not in PAIR_METHODS]
    if bad or not d.methods:
        raise ConfigError(f"data.methods = {list(d.methods)}: expected a non-empty list of 'mf', 'mw', 'nt'")
    bad = [o for o in d.orientations if o not in ("v", "h")]
    if bad or not d.orientations:
        raise ConfigError(f"data.orientations = {list(d.orientations)}: expected a non-empty list of 'v', 'h'")
    for m in PAIR_METHODS:
        f = getattr(d, f"{m}_frequencies")
        if len(f) != 2 or not all(v > 0 for v in f) or not f[1] > f[0]:
            raise ConfigError(f"data.{m}_frequencies = {list(f)}: expected [low, high] with high > low > 0")
    if d.crop and (len(d.crop) != 2 or min(d.crop) < 16):
        raise ConfigError(f"data.crop = {list(d.crop)}: expected [] or [h, w] with h, w >= 16")
    if len(d.synthetic_size) != 2 or min(d.synthetic_size) < 16:
        raise ConfigError(f"data.synthetic_size = {list(d.synthetic_size)}: expected [h, w] >= 16")
    if d.val_files and not d.train:
        raise ConfigError("data.val_files holds captures out for validation: give data.train (HDF5 files) as well")
    both = sorted(set(map(str, d.val_files)) & set(map(str, d.train)))
    if both:
        raise ConfigError(f"data.val_files and data.train share {both}: a capture is either trained on or held out")
    if cfg.run.val_score == "groups" and not d.val_files:
        raise ConfigError('run.val_score = "groups" scores per validation file: give data.val_files '
                          '(a scene split has one group only)')
    if d.split_files and not d.val_files:
        raise ConfigError("data.split_files mixes a scene split into a fine-tuning split: give data.val_files as well")
    both = sorted(set(map(str, d.split_files)) & (set(map(str, d.val_files)) | set(map(str, d.train))))
    if both:
        raise ConfigError(f"data.split_files shares {both} with data.train or data.val_files: a file is split, trained on or held out")
    if not d.train and d.synthetic_samples == 0:
        raise ConfigError("no training data: set data.train (HDF5 files) or data.synthetic_samples > 0")
    o = cfg.optim
    if not (o.lr > 0 and o.weight_decay >= 0 and o.grad_clip >= 0):
        raise ConfigError(f"optim: lr {o.lr} must be > 0, weight_decay and grad_clip >= 0")


#: ``[model]`` keys that make the architecture; a fine-tuning run (``model.init``) takes the ones
#: its file and overrides leave out from the checkpoint it starts from.
ARCH_FIELDS = ("width", "depth", "max_width", "max_correction", "conv", "norm", "stem")


def _inherit_architecture(cfg: TrainConfig, given: dict) -> TrainConfig:
    """``model.init`` set: the architecture keys not in ``given`` (the merged ``[model]`` table)
    are the init checkpoint's, so ``--init learned`` fine-tunes whatever model ships; keys that
    are given and differ are refused when the weights are loaded (``train.init_weights``)."""
    from .checkpoint import read_checkpoint
    from .runtime import model_path

    if all(k in given for k in ARCH_FIELDS):       # a run folder's config.toml: nothing to read (the file may be gone)
        return cfg
    arch = read_checkpoint(model_path(cfg.model.init))["arch"]
    default = ModelConfig()
    fill = {k: type(getattr(default, k))(arch.get(k, getattr(default, k))) for k in ARCH_FIELDS if k not in given}
    return replace(cfg, model=replace(cfg.model, **fill))


def resolve_config(path=None, overrides=()) -> TrainConfig:
    """The resolved config: defaults <- TOML file ``path`` (optional) <- ``overrides``.

    Raises :class:`ConfigError` naming an unknown key (and the closest known one), a wrong type
    or an out-of-range value.
    """
    tree = {}
    if path is not None:
        tree = read_toml(path, ConfigError, "config file")
        check_table(tree, SCHEMA, str(path), ConfigError)
    for text in overrides or ():
        check_table(apply_overrides({}, [text], ConfigError), SCHEMA, "overrides", ConfigError)
    merged = apply_overrides(tree, overrides, ConfigError)
    cfg = from_table(TrainConfig, merged, "config", ConfigError)
    if cfg.model.init:
        cfg = _inherit_architecture(cfg, merged.get("model") or {})
    if cfg.model.init and "lr" not in (merged.get("optim") or {}):
        cfg = replace(cfg, optim=replace(cfg.optim, lr=FINETUNE_LR))
    _check(cfg)
    return cfg


def to_toml(cfg: TrainConfig) -> str:
    """The resolved config as TOML text (what a run folder keeps as ``config.toml``; read back by
    :func:`resolve_config` to an equal config, ``inf`` included)."""
    return tomli_w.dumps(to_table(cfg))


#: The schema of the TOML (section -> key -> type), from :class:`TrainConfig`.
SCHEMA = schema_of(TrainConfig)
