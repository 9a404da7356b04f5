"""A small in-memory fringe-order dataset made with ``unwrap``'s own functions (no renderer).

It serves the same item dict as :class:`unwrap.dataset.FringeOrderDataset` (the contract in
``docs/learned.md``), so the model, the training loop and their tests run without an exported
HDF5 file, in seconds. Each sample is drawn from ``(seed, index)`` alone:

- a camera image ``size = (H, W)`` of a projector coordinate map ``u`` (px across the fringes): a
  tilted plane (0.8-1.6 projector px per camera px, the built-in system's scale), smooth relief
  (1-12 px of parallax, i.e. up to ~50 mm of depth, over 15-50 camera px), and one object whose
  parallax shifts ``u`` by up to 40 px at its silhouette, with a cast-shadow band
  beside it and an unlit border where ``u`` leaves the pattern;
- albedo texture, exposure and ambient light (``A``, ``B`` of ``I_n = A + B cos(Phi - 2 pi n/N)``);
- a **low-frequency bias** standing for global illumination: light arriving from another surface
  (a blurred, shifted copy of the direct fringe image, 0-``indirect`` of it). Wide blurs average
  high-frequency fringes away, so it biases the phase of the unit / beat pattern coherently over
  whole regions (the error a network must learn to fix, beside noise); subsurface scattering (a
  narrow blur inside the object) and camera defocus lower the contrast of fine fringes;
- Gaussian sensor noise (``noise`` = sigma range in full-scale units) and 8-bit quantisation,
  then the N-step wrapped phase (:func:`unwrap.wrapped_phase`) and the method's prior and order
  (:func:`unwrap.temporal.decode_pair`, the reader's own: ``mf_unwrap`` / ``mw_unwrap`` / ``nt_unwrap``).

Each effect has a range argument (``noise``, ``indirect``, ``subsurface``, ``defocus``); zero ranges
give the ideal stack, on which the traditional order is exact (tested).

SYNOPSIS

    >>> from unwrap.learned.synthetic import SyntheticFringeDataset
    >>> ds = SyntheticFringeDataset(4, size=(48, 64), method="mf", frequencies=(1, 48))
    >>> item = ds[0]
    >>> tuple(item["prior"].shape), item["order_true"].dtype, bool(item["valid"].any())
    ((1, 48, 64), torch.int64, True)
"""
from __future__ import annotations

import math

import numpy as np
import torch
from scipy import ndimage
from torch.utils.data import Dataset

from .._xp import TWO_PI, round_order
from ..methods import check_pair as _check_pair
from ..phase_shift import wrapped_phase
from ..temporal import decode_pair
from .errors import ModelError

#: Projector pixels across the fringes per orientation (the built-in DLP4500: 912 x 1140).
PATTERN_WIDTH = {"v": 912.0, "h": 1140.0}
#: Valid pixels: modulation above this fraction of full scale (the export's default).
MIN_MODULATION = 0.02


def check_pair(method: str, f_lo: float, f_hi: float) -> None:
    """Refuse a (method, (low, high)) pair the decoders cannot use (:class:`ModelError`; the rule:
    :func:`unwrap.methods.check_pair`)."""
    _check_pair(method, f_lo, f_hi, ModelError)


def _smooth_field(rng, shape, corr_px: float) -> np.ndarray:
    """Zero-mean, unit-RMS Gaussian random field with correlation length ``corr_px``."""
    f = ndimage.gaussian_filter(rng.standard_normal(shape), corr_px, mode="reflect")
    return f / (f.std() + 1e-12)


def _blob(rng, shape) -> np.ndarray:
    """A random smooth blob (object silhouette) covering 15-45 % of the image, bool (H, W)."""
    H, W = shape
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    cy, cx = rng.uniform(0.25, 0.75) * H, rng.uniform(0.25, 0.75) * W
    ry, rx = rng.uniform(0.2, 0.4) * H, rng.uniform(0.2, 0.4) * W
    d = ((yy - cy) / ry) ** 2 + ((xx - cx) / rx) ** 2
    return d + 0.35 * _smooth_field(rng, shape, 0.08 * min(H, W)) < 1.0


def synthetic_sample(index: int, *, size=(96, 128), method: str = "mf", frequencies=(1, 48),
                     orientation: str = "v", seed: int = 0, steps: int = 12, noise=(0.002, 0.012),
                     indirect=(0.0, 0.1), subsurface=(0.0, 0.5), defocus=(0.0, 1.2)) -> dict:
    """One sample as numpy arrays (the item dict before the conversion to tensors)."""
    f_lo, f_hi = (float(f) for f in frequencies)
    check_pair(method, f_lo, f_hi)
    if orientation not in PATTERN_WIDTH:
        raise ModelError(f"orientation {orientation!r}: expected 'v' or 'h'")
    H, W = (int(v) for v in size)
    if H < 16 or W < 16:
        raise ModelError(f"synthetic image size {size}: expected at least 16 x 16 pixels")
    rng = np.random.default_rng([int(seed), int(index)])
    width = PATTERN_WIDTH[orientation]
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    a = rng.normal(0.0, 0.15)
    along = (xx * math.cos(a) + yy * math.sin(a)) if orientation == "v" else (yy * math.cos(a) + xx * math.sin(a))
    g = rng.uniform(0.8, 1.6) * rng.choice((-1.0, 1.0))
    # relief: 1 projector px of parallax is ~4 mm of depth at the built-in system's 800 mm
    u = g * along + rng.uniform(1, 12) * _smooth_field(rng, (H, W), rng.uniform(15, 50))
    obj = _blob(rng, (H, W))
    step = rng.uniform(-40, 40)
    u = u + np.where(obj, step + rng.uniform(0.5, 6) * _smooth_field(rng, (H, W), rng.uniform(8, 30)), 0.0)
    u = u - u.min() + rng.uniform(-20, max(width - (u.max() - u.min()), 0.0))
    # cast shadow: the object's silhouette moved sideways, outside the object
    dy, dx = rng.integers(-6, 7, size=2)
    shadow = np.roll(obj, (int(dy), int(dx)), axis=(0, 1)) & ~obj
    lit = (u >= -0.5) & (u < width - 0.5) & ~shadow
    albedo = np.clip(0.62 + 0.33 * _smooth_field(rng, (H, W), rng.uniform(3, 20)) * rng.uniform(0.2, 1.0), 0.3, 0.95)
    exposure, ambient = rng.uniform(0.45, 0.95), rng.uniform(0.0, 0.08)
    A = albedo * (ambient + np.where(lit, 0.5 * exposure, 0.0))
    B = albedo * np.where(lit, 0.5 * exposure, 0.0)
    r_ind = rng.uniform(*indirect)
    shift = rng.normal(0.0, 60.0, size=2)        # light from surfaces ~60 px away
    sigma_ind = rng.uniform(10.0, 40.0)
    sub, sigma_sub = rng.uniform(*subsurface), rng.uniform(0.5, 3.0)
    defocus = rng.uniform(*defocus)
    sigma_noise = rng.uniform(*noise)
    phases, mods, flags = {}, {}, {}
    for f in (f_lo, f_hi):
        Phi = TWO_PI * f * u / width
        stack = np.empty((steps, H, W), dtype=np.uint8)
        for n in range(steps):
            direct = A + B * np.cos(Phi - TWO_PI * n / steps)
            lobj = np.where(obj, direct, 0.0)
            direct = direct + sub * (np.where(obj, ndimage.gaussian_filter(lobj, sigma_sub), 0.0) - lobj)
            moved = ndimage.shift(direct, shift, order=1, mode="nearest")
            img = direct + r_ind * ndimage.gaussian_filter(moved, sigma_ind, mode="nearest")
            if defocus > 0.3:
                img = ndimage.gaussian_filter(img, defocus, mode="nearest")
            img = img + sigma_noise * rng.standard_normal((H, W))
            stack[n] = np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)
        w = wrapped_phase(stack, min_modulation=MIN_MODULATION * 255.0)
        phases[f] = np.nan_to_num(w.phase)
        mods[f] = w.B / 255.0
        flags[f] = w.valid
    valid = lit & flags[f_lo] & flags[f_hi]
    prior, order_trad, valid = decode_pair(method, phases[f_lo], phases[f_hi], f_lo, f_hi, width, valid)
    Phi_true = TWO_PI * f_hi * u / width
    order_true = np.where(valid, round_order((Phi_true - phases[f_hi]) / TWO_PI), -1).astype(np.int64)
    zero = lambda x: np.where(valid, x, 0.0)  # noqa: E731
    return {"prior": prior, "phase_low": zero(phases[f_lo]), "phase_high": zero(phases[f_hi]),
            "modulation_low": zero(mods[f_lo]), "modulation_high": zero(mods[f_hi]),
            "order_traditional": order_trad, "order_true": order_true, "valid": valid,
            "frequency_low": f_lo, "frequency_high": f_hi, "index": int(index), "has_reference": True}


def to_item(sample: dict) -> dict:
    """numpy sample -> the contract's tensors: (1,H,W) float32 inputs, (H,W) int64 orders / bool."""
    item = {}
    for key, a in sample.items():
        if key in ("order_traditional", "order_true"):
            item[key] = torch.from_numpy(np.ascontiguousarray(a, dtype=np.int64))
        elif key == "valid":
            item[key] = torch.from_numpy(np.ascontiguousarray(a, dtype=bool))
        elif key in ("frequency_low", "frequency_high"):
            item[key] = torch.tensor(float(a), dtype=torch.float64)
        elif key == "index":
            item[key] = torch.tensor(int(a), dtype=torch.int64)
        elif key == "has_reference":
            item[key] = torch.tensor(bool(a))
        else:
            item[key] = torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))[None]
    return item


class SyntheticFringeDataset(Dataset):
    """``n_samples`` synthetic samples (see the module docstring), made on first access and kept.

    ARGUMENTS: n_samples; size (H, W); method ("mf", "mw", "nt"); frequencies (low, high) as the
    reader's; orientation; seed; noise (sigma range, full scale); indirect (range of the
    low-frequency bias fraction); samples: optional index subset (a train/validation split).
    ``attrs`` and ``available_frequencies`` mirror the reader's.
    """

    def __init__(self, n_samples: int, *, size=(96, 128), method: str = "mf", frequencies=(1, 48),
                 orientation: str = "v", seed: int = 0, noise=(0.002, 0.012), indirect=(0.0, 0.1),
                 subsurface=(0.0, 0.5), defocus=(0.0, 1.2), samples=None):
        if int(n_samples) < 0:
            raise ModelError(f"n_samples = {n_samples}: expected >= 0")
        check_pair(method, float(frequencies[0]), float(frequencies[1]))
        self.n_samples = int(n_samples)
        self.kw = dict(size=tuple(int(v) for v in size), method=method,
                       frequencies=tuple(float(f) for f in frequencies), orientation=orientation,
                       seed=int(seed), noise=tuple(noise), indirect=tuple(indirect),
                       subsurface=tuple(subsurface), defocus=tuple(defocus))
        self.method, self.orientation = method, orientation
        self.f_lo, self.f_hi = self.kw["frequencies"]
        self.samples = np.arange(self.n_samples) if samples is None else np.asarray(samples, dtype=np.int64)
        self.attrs = {"kind": "synthetic", **self.kw, "n_samples": self.n_samples, "widths": dict(PATTERN_WIDTH)}
        self.available_frequencies = list(self.kw["frequencies"])
        self._cache: dict = {}

    def __len__(self) -> int:
        return int(self.samples.size)

    def set_epoch(self, epoch: int):
        """Items do not change between epochs (no crops); kept for the reader's interface."""

    def __getitem__(self, i: int) -> dict:
        g = int(self.samples[i])
        if g not in self._cache:
            self._cache[g] = to_item(synthetic_sample(g, **self.kw))
        return self._cache[g]
