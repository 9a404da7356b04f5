"""Learned fringe-order unwrapping: the physics-aware network (the paper's DP-TPU idea), its
prior-free baseline (DT-TPU), losses, training, evaluation and use (docs/learned.md).

Public surface: ``train`` (the training loop, ``calib train``), ``resolve_config``, ``load_model``,
``unwrap_learned`` (apply a model to one orientation's wrapped phases), ``shipped_model_path``,
``filtered_order`` (the classical filtered baseline), ``SyntheticFringeDataset`` (the in-memory
dataset of the contract), ``ErrorCount`` / ``keep_drop_curve`` (metrics), the error types.
Names are imported on first use (PEP 562), so ``unwrap.learned.infer`` / ``.capture`` /
``.runtime`` load without torch (an ONNX model runs without it); ``train``, ``load_model`` and
the datasets import torch when touched. ``unwrap`` itself does not import this package.
"""
_PUBLIC = {
    "filtered_order": "baselines", "export_model": "checkpoint", "load_model": "checkpoint",
    "resolve_config": "config", "CheckpointError": "errors", "ConfigError": "errors",
    "DatasetTooSmallError": "errors", "FrequencyRangeWarning": "errors", "ModelError": "errors",
    "LearnedResult": "infer", "check_frequency_range": "infer", "shipped_model_path": "infer",
    "unwrap_learned": "infer", "ErrorCount": "metrics", "keep_drop_curve": "metrics",
    "SyntheticFringeDataset": "synthetic", "TrainResult": "train", "train": "train",
    "load_predictor": "runtime", "export_onnx": "runtime",
}
__all__ = sorted(_PUBLIC)


def _module(name):
    """The submodule that defines a public name (static imports: the floor plan sees them)."""
    where = _PUBLIC[name]
    if where == "baselines":
        from . import baselines as m
    elif where == "checkpoint":
        from . import checkpoint as m
    elif where == "config":
        from . import config as m
    elif where == "errors":
        from . import errors as m
    elif where == "infer":
        from . import infer as m
    elif where == "metrics":
        from . import metrics as m
    elif where == "synthetic":
        from . import synthetic as m
    elif where == "runtime":
        from . import runtime as m
    else:
        from . import train as m
    return m


def __getattr__(name):
    if name in _PUBLIC:
        value = getattr(_module(name), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
