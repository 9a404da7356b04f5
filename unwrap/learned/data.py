"""Training data from a config: the HDF5 reader or the synthetic set, per (method, orientation),
split by scene into training and validation, with a resumable, rank-aware sampler.

Every dataset item is the contract's dict (``unwrap.dataset``) plus ``method`` (0 mf, 1 mw, 2 nt).
The split is by scene index, shared by every method and orientation, so no validation scene is
ever seen in training.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import ConcatDataset, Dataset, Sampler

from .errors import DatasetTooSmallError
from .features import METHOD_INDEX

#: Refuse training sets smaller than this many scenes (after the validation split).
MIN_TRAIN_SCENES = 2


class MethodTagged(Dataset):
    """Adds ``method`` (int64) to every item of a contract dataset."""

    def __init__(self, ds, method: str):
        self.ds, self.method = ds, method
        self._m = torch.tensor(METHOD_INDEX[method], dtype=torch.int64)

    def __len__(self):
        return len(self.ds)

    def set_epoch(self, epoch: int):
        if hasattr(self.ds, "set_epoch"):
            self.ds.set_epoch(epoch)

    def __getitem__(self, i):
        item = dict(self.ds[i])
        item["method"] = self._m
        return item


class EpochDataset(ConcatDataset):
    """ConcatDataset whose ``set_epoch`` reaches every part (crops and flips change per epoch)."""

    def set_epoch(self, epoch: int):
        for d in self.datasets:
            if hasattr(d, "set_epoch"):
                d.set_epoch(epoch)


def _scene_count(cfg, files=None) -> int:
    """Scenes of ``files`` (default ``data.train``; none: ``data.synthetic_samples``)."""
    d = cfg.data
    files = d.train if files is None else files
    if files:
        from ..dataset import FringeOrderDataset   # the HDF5 reader (unwrap/dataset.py)
        m = d.methods[0]
        ds = FringeOrderDataset(list(files), method=m, frequencies=d.frequencies(m),
                                orientation=d.orientations[0], crop=None, seed=0)
        return len(ds)
    return int(d.synthetic_samples)


def split_scenes(n: int, val_fraction: float, val_max: int, seed: int):
    """(train indices, val indices) of ``n`` scenes: a seeded random ``val_fraction`` (at most
    ``val_max``, at least 1 when the fraction is > 0) held out for validation."""
    rng = np.random.default_rng([int(seed), 7])
    perm = rng.permutation(n)
    n_val = 0 if val_fraction <= 0 else min(max(1, int(round(n * val_fraction))), int(val_max), n)
    return np.sort(perm[n_val:]), np.sort(perm[:n_val])


def _one(cfg, method: str, orientation: str, samples, train: bool, files=None):
    """One (method, orientation) part of the scenes ``samples`` of ``files`` (default
    ``data.train``; none: the synthetic scenes)."""
    d = cfg.data
    freqs = d.frequencies(method)
    seed = int(cfg.run.seed)
    files = d.train if files is None else files
    if files:
        from ..dataset import FringeOrderDataset
        crop = tuple(d.crop) if (train and d.crop) else None
        ds = FringeOrderDataset(list(files), method=method, frequencies=freqs, orientation=orientation,
                                crop=crop, flip=bool(d.flip) and train, samples=samples, seed=seed)
    else:
        from .synthetic import SyntheticFringeDataset
        ds = SyntheticFringeDataset(int(d.synthetic_samples), size=tuple(d.synthetic_size), method=method,
                                    frequencies=freqs, orientation=orientation, seed=seed, samples=samples)
    return MethodTagged(ds, method)


def _file_orientations(path, wanted) -> list:
    """The orientations of ``wanted`` that the dataset file ``path`` holds."""
    import h5py

    from ..dataset_schema import read_attrs
    with h5py.File(path, "r") as h5:
        have = read_attrs(h5)["orientations"]
    return [o for o in wanted if o in have]


def _by_file(cfg, files, train: bool):
    """One dataset per (file, method, orientation the file holds): whole files, no sample split."""
    from ..dataset import FringeOrderDataset
    d, seed = cfg.data, int(cfg.run.seed)
    parts = []
    for p in files:
        orients = _file_orientations(p, d.orientations)
        if not orients:
            raise DatasetTooSmallError(f"{p}: holds none of the orientations {list(d.orientations)} (data.orientations)")
        for m in d.methods:
            for o in orients:
                crop = tuple(d.crop) if (train and d.crop) else None
                ds = FringeOrderDataset(p, method=m, frequencies=d.frequencies(m), orientation=o,
                                        crop=crop, flip=bool(d.flip) and train, seed=seed)
                part = MethodTagged(ds, m)
                part.group = Path(p).name
                parts.append(part)
    return parts


def _split_parts(cfg, files):
    """``data.split_files``: the files' scenes split as a from-scratch run on them as ``data.train``
    splits them (:func:`split_scenes` with ``val_fraction``, ``val_samples``, ``run.seed``), so a
    fine-tune on a mix keeps that run's validation scenes out of training. (train parts, val
    parts, held-out scene indices)."""
    d = cfg.data
    tr, va = split_scenes(_scene_count(cfg, files), d.val_fraction, d.val_samples, cfg.run.seed)
    parts = {train: [_one(cfg, m, o, idx, train, files) for m in d.methods for o in d.orientations]
             for train, idx in ((True, tr), (False, va))}
    return parts[True], parts[False], va


def build_by_capture(cfg):
    """Fine-tuning split (``data.val_files`` given): every file of ``data.train`` trains, every file
    of ``data.val_files`` validates; a file is one capture (or a disjoint half of one), so no pixel
    of a validation capture is ever trained on. Each file serves the orientations it holds.
    ``data.split_files`` (optional) adds files split by scene (:func:`_split_parts`). Every
    validation part carries ``group``: its file's name, or ``"split"`` (per-group error rates)."""
    d = cfg.data
    tr_parts, va_parts = _by_file(cfg, d.train, True), _by_file(cfg, d.val_files, False)
    split = []
    if d.split_files:
        s_tr, s_va, split = _split_parts(cfg, d.split_files)
        for part in s_va:
            part.group = "split"
        tr_parts, va_parts = s_tr + tr_parts, s_va + va_parts
    train, val = EpochDataset(tr_parts), EpochDataset(va_parts)
    info = {"scenes": len(d.train) + len(d.val_files), "train_scenes": [str(p) for p in d.train],
            "val_scenes": [str(p) for p in d.val_files] + [f"split:{int(i)}" for i in split],
            "train_items": len(train), "val_items": len(val), "split": "by file (capture)"}
    return train, val, info


def build_datasets(cfg):
    """(train dataset, val dataset or None, info dict) of a resolved config (:func:`build_by_capture`
    when ``data.val_files`` is given).

    Raises :class:`DatasetTooSmallError` when fewer than :data:`MIN_TRAIN_SCENES` training scenes
    remain after the split.
    """
    d = cfg.data
    if d.val_files:
        return build_by_capture(cfg)
    n = _scene_count(cfg)
    tr, va = split_scenes(n, d.val_fraction, d.val_samples, cfg.run.seed)
    if tr.size < MIN_TRAIN_SCENES:
        raise DatasetTooSmallError(
            f"training set too small: {n} scene(s), {tr.size} left for training after holding out {va.size} for "
            f"validation; need at least {MIN_TRAIN_SCENES} (source: {list(d.train) or 'synthetic'})")
    train = EpochDataset([_one(cfg, m, o, tr, True) for m in d.methods for o in d.orientations])
    val = EpochDataset([_one(cfg, m, o, va, False) for m in d.methods for o in d.orientations]) \
        if va.size else None
    info = {"scenes": int(n), "train_scenes": tr.tolist(), "val_scenes": va.tolist(),
            "train_items": len(train), "val_items": 0 if val is None else len(val)}
    return train, val, info


class ResumableSampler(Sampler):
    """Indices of one epoch for one rank: a permutation seeded by ``(seed, epoch)`` (the same on
    every rank), padded to a multiple of ``world``, rank ``r`` taking positions ``r, r + world, ...``
    and skipping its first ``start`` indices (to resume in the middle of an epoch).

    With ``world = 1`` the first ``2 b`` indices are exactly the union of the first ``b`` indices
    of two ranks, so one step of 1 x 2b and 2 x b see the same samples.
    """

    def __init__(self, n: int, *, seed: int = 0, rank: int = 0, world: int = 1, shuffle: bool = True):
        self.n, self.seed, self.rank, self.world, self.shuffle = int(n), int(seed), int(rank), int(world), shuffle
        self.epoch, self.start = 0, 0

    def set_epoch(self, epoch: int, start: int = 0):
        self.epoch, self.start = int(epoch), int(start)

    def per_rank(self) -> int:
        return math.ceil(self.n / self.world)

    def __len__(self):
        return max(self.per_rank() - self.start, 0)

    def __iter__(self):
        if self.shuffle:
            g = torch.Generator()
            g.manual_seed(self.seed * 1_000_003 + self.epoch)
            idx = torch.randperm(self.n, generator=g).tolist()
        else:
            idx = list(range(self.n))
        total = self.per_rank() * self.world
        idx = idx + idx[: total - len(idx)]
        mine = idx[self.rank:total:self.world]
        return iter(mine[self.start:])
