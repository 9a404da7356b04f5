"""Learned fringe-order unwrapping: the physics-aware network (the paper's DP-TPU idea), its
prior-free baseline (DT-TPU), losses, training, evaluation and use (docs/learned.md).

Public surface: ``train`` (the training loop, ``calib train``), ``resolve_config``, ``load_model``,
``unwrap_learned`` (apply a model to one orientation's wrapped phases), ``shipped_model_path``,
``filtered_order`` (the classical filtered baseline), ``SyntheticFringeDataset`` (the in-memory
dataset of the contract), ``ErrorCount`` / ``keep_drop_curve`` (metrics), the error types.
Torch is imported with the package; ``unwrap`` itself does not import this package.
"""
from .baselines import filtered_order  # noqa: F401
from .checkpoint import export_model, load_model  # noqa: F401
from .config import resolve_config  # noqa: F401
from .errors import (CheckpointError, ConfigError, DatasetTooSmallError, FrequencyRangeWarning,  # noqa: F401
                     ModelError)
from .infer import LearnedResult, check_frequency_range, shipped_model_path, unwrap_learned  # noqa: F401
from .metrics import ErrorCount, keep_drop_curve  # noqa: F401
from .synthetic import SyntheticFringeDataset  # noqa: F401
from .train import TrainResult, train  # noqa: F401
