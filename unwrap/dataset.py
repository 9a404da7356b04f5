"""Read fringe-order datasets (twin exports and real captures, unwrap.dataset_schema) as torch
samples for a chosen method and frequency pair.

SYNOPSIS

    from unwrap.dataset import FringeOrderDataset
    ds = FringeOrderDataset("data/train.h5", method="mf", frequencies=(1, 48), orientation="v",
                            crop=(256, 256), flip=True, seed=0)
    item = ds[0]        # dict of tensors: prior, phase_low, phase_high, modulation_low/high,
                        # order_traditional, order_true, valid, frequency_low/high, index, has_reference
    loader = torch.utils.data.DataLoader(ds, batch_size=8, num_workers=2)   # fork or spawn

Nothing method-specific is stored: the physics prior and the traditional order are computed here
from the stored wrapped phases by unwrap's own functions (``mf_unwrap``, ``mw_unwrap``,
``nt_unwrap``), in float64, and cast to float32 at the end. The file is opened lazily in each
process (never before a worker forks or is spawned), so the dataset works with DataLoader
workers under both start methods.

Methods and pairs (``frequencies`` = (low, high); the order returned is always the high one's):

- ``mf``: (unit, high), unit <= 1 period; prior = eq. 7 of the paper's supplementary.
- ``mw``: a close pair f2 > f1 whose beat f2 - f1 <= 1 period; prior of f2 relative to the beat.
- ``nt``: a coprime integer pair; prior = the real-valued residue (f1 phi2 - f2 phi1) / 2 pi (an
  integer when noise-free, not an order), and the traditional order comes from the lookup table.

``order_true``: for twin files the order that makes the *measured* wrapped phase of the high
frequency absolute, ``round((Phi_true - phi) / 2 pi)`` with ``Phi_true = 2 pi f c / width`` from
the stored true projector coordinate ``c``. It equals the geometric order except where noise moved
the wrapped phase across its +-pi cut (there the geometric order would count a correct
unwrapping as wrong). For real captures it is the stored reference order (-1 where none).
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from ._xp import TWO_PI, round_order
from .dataset_schema import (FLAG_LOW_MODULATION, FLAG_OUT_OF_RANGE, FLAG_SATURATED, MASK_LIT,
                             DatasetSchemaError, check_schema, decode_modulation, decode_phase,
                             orientation_frequencies)
from .errors import UnwrapError
from .methods import check_pair
from .temporal import decode_pair

_BAD = FLAG_LOW_MODULATION | FLAG_SATURATED | FLAG_OUT_OF_RANGE


class FringeOrderDataset(Dataset):
    """A torch Dataset over one or more dataset files (see the module docstring and
    docs/dataset.md: the interface the model consumes).

    ARGUMENTS
    - path_or_paths: one .h5 file (a shard or a combined file) or a list of them.
    - method, frequencies, orientation: what to serve (checked against the files).
    - crop: None or (h, w): a random window, the same for a given (seed, epoch, index) when
      ``seed`` is not None (:meth:`set_epoch`); flip: random horizontal / vertical flips.
    - samples: optional subset of indices (e.g. a train/validation split).
    - seed: None for fresh randomness, else the base of the per-item generators."""

    def __init__(self, path_or_paths, method: str = "mf", frequencies=(1, 48), orientation: str = "v",
                 crop=None, flip: bool = False, samples=None, seed: int | None = 0):
        import h5py

        paths = [path_or_paths] if isinstance(path_or_paths, (str, os.PathLike)) else list(path_or_paths)
        if not paths:
            raise UnwrapError("FringeOrderDataset: no file given")
        self.paths = [Path(p) for p in paths]
        f_lo, f_hi = (float(f) for f in frequencies)
        check_pair(method, f_lo, f_hi)
        if orientation not in ("v", "h"):
            raise UnwrapError(f"orientation {orientation!r}: expected 'v' or 'h'")
        self.method, self.f_lo, self.f_hi, self.orientation = method, f_lo, f_hi, orientation
        self.files = []   # (path, n_samples, j_lo, j_hi, width, kind, (W, H))
        for p in self.paths:
            if not p.exists():
                raise FileNotFoundError(f"dataset file not found: {p}")
            try:
                with h5py.File(p, "r") as h5:
                    attrs = check_schema(h5, str(p))
                    has_ref = f"{orientation}/reference_order" in h5
                    freqs = orientation_frequencies(h5, orientation) if orientation in h5 else []
            except OSError as exc:
                raise DatasetSchemaError(f"{p}: not a readable HDF5 file ({exc})") from None
            if orientation not in attrs["orientations"]:
                raise UnwrapError(f"{p}: holds orientation(s) {attrs['orientations']}, not {orientation!r}")
            miss = [f for f in (f_lo, f_hi) if f not in freqs]
            if miss:
                raise UnwrapError(f"{p}: frequencies {[f'{f:g}' for f in miss]} not in the file (it holds "
                                  f"{[f'{f:g}' for f in freqs]})")
            self.files.append((p, int(attrs["n_samples"]), freqs.index(f_lo), freqs.index(f_hi),
                               float(attrs["widths"][orientation]), attrs["kind"], tuple(attrs["camera_size"]),
                               has_ref))
            if len(self.files) == 1:
                self.attrs = attrs
                self.available_frequencies = freqs
        self.attrs = {**self.attrs, "files": [str(p) for p in self.paths]}
        self._offsets = np.cumsum([0] + [f[1] for f in self.files])
        total = int(self._offsets[-1])
        self.samples = np.arange(total) if samples is None else np.asarray(samples, dtype=np.int64)
        if self.samples.size and (self.samples.min() < 0 or self.samples.max() >= total):
            raise UnwrapError(f"samples: indices must lie in [0, {total}), got {self.samples.min()}..{self.samples.max()}")
        if crop is not None:
            ch, cw = (int(v) for v in crop)
            for f in self.files:
                W, H = f[6]
                if not (0 < ch <= H and 0 < cw <= W):
                    raise UnwrapError(f"crop {crop}: must fit the {W}x{H} images of {f[0]}")
            crop = (ch, cw)
        self.crop, self.flip, self.seed = crop, bool(flip), seed
        self.epoch = 0
        self._handles: dict = {}
        self._pid = None

    # -- torch Dataset protocol --
    def __len__(self) -> int:
        return int(self.samples.size)

    def set_epoch(self, epoch: int):
        """Change the crops and flips of every item (seeded: reproducible per epoch)."""
        self.epoch = int(epoch)

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_handles"], state["_pid"] = {}, None   # never pickle an open file into a worker
        return state

    def _h5(self, j: int):
        import h5py

        if self._pid != os.getpid():
            self._handles, self._pid = {}, os.getpid()
        h = self._handles.get(j)
        if h is None:
            h = self._handles[j] = h5py.File(self.files[j][0], "r")
        return h

    def __getitem__(self, i: int) -> dict:
        try:
            return self._item(i)
        except (OSError, KeyError, RuntimeError) as exc:   # a truncated or damaged file: name it and the sample
            g = int(self.samples[i])
            path = self.files[int(np.searchsorted(self._offsets, g, side="right") - 1)][0]
            raise DatasetSchemaError(f"{path}: sample {g} cannot be read (a truncated or damaged file?): "
                                     f"{type(exc).__name__}: {str(exc)[:200]}") from None

    def _item(self, i: int) -> dict:
        g = int(self.samples[i])
        j = int(np.searchsorted(self._offsets, g, side="right") - 1)
        k = g - int(self._offsets[j])
        path, _, jl, jh, width, kind, (W, H), has_ref = self.files[j]
        rng = np.random.default_rng(None if self.seed is None else [self.seed, self.epoch, g])
        if self.crop is not None:
            ch, cw = self.crop
            y0, x0 = int(rng.integers(H - ch + 1)), int(rng.integers(W - cw + 1))
            win = (slice(y0, y0 + ch), slice(x0, x0 + cw))
        else:
            win = (slice(None), slice(None))
        h5 = self._h5(j)
        o = self.orientation
        ph = h5[f"{o}/phase"]
        phi_lo, phi_hi = decode_phase(ph[(k, jl) + win]), decode_phase(ph[(k, jh) + win])
        mod = h5[f"{o}/modulation"]
        m_lo, m_hi = decode_modulation(mod[(k, jl) + win]), decode_modulation(mod[(k, jh) + win])
        fl = h5[f"{o}/flags"]
        valid = ((h5["masks"][(k,) + win] & MASK_LIT) != 0) & ((fl[(k, jl) + win] & _BAD) == 0) \
            & ((fl[(k, jh) + win] & _BAD) == 0)
        prior, order_trad, valid = decode_pair(self.method, phi_lo, phi_hi, self.f_lo, self.f_hi, width, valid)
        if kind == "twin":
            coord = h5[f"{o}/coordinate"][(k,) + win].astype(np.float64)
            Phi = TWO_PI * self.f_hi * np.nan_to_num(coord) / width
            order_true = np.where(valid, round_order((Phi - phi_hi) / TWO_PI), -1).astype(np.int64)
            has_reference = True
        else:
            ref = h5[f"{o}/reference_order"][(k, jh) + win].astype(np.int64) if has_ref else np.full(valid.shape, -1)
            order_true = np.where(valid, ref, -1)
            has_reference = bool((order_true >= 0).any())
        out = {"prior": prior, "phase_low": np.where(valid, phi_lo, 0.0), "phase_high": np.where(valid, phi_hi, 0.0),
               "modulation_low": np.where(valid, m_lo, 0.0), "modulation_high": np.where(valid, m_hi, 0.0),
               "order_traditional": order_trad, "order_true": order_true, "valid": valid}
        if self.flip:
            fx, fy = bool(rng.integers(2)), bool(rng.integers(2))
            for key, a in out.items():
                a = a[:, ::-1] if fx else a
                out[key] = a[::-1] if fy else a
        item = {}
        for key, a in out.items():
            a = np.ascontiguousarray(a)
            if key in ("order_traditional", "order_true"):
                item[key] = torch.from_numpy(a.astype(np.int64))
            elif key == "valid":
                item[key] = torch.from_numpy(a.astype(bool))
            else:
                item[key] = torch.from_numpy(a.astype(np.float32))[None]
        item.update(frequency_low=torch.tensor(self.f_lo, dtype=torch.float64),
                    frequency_high=torch.tensor(self.f_hi, dtype=torch.float64),
                    index=torch.tensor(g, dtype=torch.int64), has_reference=torch.tensor(has_reference))
        return item

    def close(self):
        for h in self._handles.values():
            h.close()
        self._handles = {}


def open_dataset(path_or_paths, **kwargs) -> FringeOrderDataset:
    """``FringeOrderDataset(path_or_paths, **kwargs)`` (the same checks, a shorter name)."""
    return FringeOrderDataset(path_or_paths, **kwargs)
