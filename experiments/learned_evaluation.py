"""Score models and baselines on held-out test data: the S5 / S6 layouts, real captures, speed.

Error rate and mask rule: :mod:`unwrap.learned.metrics` (wrong orders / pixels with valid inputs
and a true or reference order; every method on the same pixels). Frequency pairs per fringe
frequency ``f``: MF ``(1, f)``, MW ``(f - 1, f)`` (beat of one period), NT ``(f - 1, f)`` (coprime).

SYNOPSIS

    from experiments.learned_evaluation import TestSource, score
    src = TestSource(files=["test.h5"])                       # or TestSource(synthetic=(20, (96, 128), 5))
    rows = score(src, "mf", 96, {"DP-TPU": "runs/a/model.pt"})
    rows["Traditional"].rate, rows["DP-TPU"].rate
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from unwrap.methods import pair_at
from unwrap.learned.baselines import filtered_order
from unwrap.learned.checkpoint import load_model
from unwrap.learned.data import MethodTagged
from unwrap.learned.errors import ModelError
from unwrap.learned.features import METHOD_INDEX, make_inputs
from unwrap.learned.infer import check_frequency_range, predict
from unwrap.learned.metrics import ErrorCount, keep_drop_curve

log = logging.getLogger("experiments")

DROPS = (0.0, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2)


@dataclass
class TestSource:
    """Where test items come from: HDF5 ``files`` (the reader) or ``synthetic`` = (n, (H, W), seed).

    ``orientations`` to score; ``max_samples``: at most this many scenes (the first ones).
    ``label``: a name for reports."""
    files: list = field(default_factory=list)
    synthetic: tuple | None = None
    orientations: tuple = ("v", "h")
    max_samples: int | None = None
    label: str = ""

    def dataset(self, method: str, f: float, orientation: str):
        """The contract dataset of one (method, f, orientation), or None when the source lacks the pair."""
        pair = pair_at(method, f, ModelError)
        if self.files:
            from unwrap.dataset import FringeOrderDataset
            if not _files_hold(self.files, pair, orientation):
                log.info("skip %s f=%g %s: not in %s", method, f, orientation, self.files)
                return None
            ds = FringeOrderDataset(self.files, method=method, frequencies=pair, orientation=orientation,
                                    crop=None, flip=False, seed=0)
        elif self.synthetic is not None:
            from unwrap.learned.synthetic import SyntheticFringeDataset
            n, size, seed = self.synthetic
            ds = SyntheticFringeDataset(n, size=size, method=method, frequencies=pair, orientation=orientation,
                                        seed=seed)
        else:
            raise ModelError("TestSource: give files or synthetic")
        if self.max_samples is not None and len(ds) > self.max_samples:
            ds.samples = ds.samples[: self.max_samples]
        return MethodTagged(ds, method)


def _files_hold(files, pair, orientation: str) -> bool:
    """Whether every file holds both frequencies of ``pair`` and the orientation."""
    import h5py

    from unwrap.dataset_schema import read_attrs
    for p in files:
        with h5py.File(p, "r") as h5:
            a = read_attrs(h5)
        freqs = [float(f) for f in a.get("frequencies", [])]
        if orientation not in a.get("orientations", []) or any(float(f) not in freqs for f in pair):
            return False
    return True


def _models(models: dict) -> dict:
    return {name: (m if isinstance(m, tuple) else load_model(m)) for name, m in models.items()}


@dataclass
class Scored:
    """Error counts per row, plus the confidence of each model's counted pixels (for curves)."""
    counts: dict
    confidence: dict
    wrong: dict
    checks: dict
    items: int = 0


def score(source: TestSource, method: str, f: float, models: dict, *, filtered_window: int | None = 15,
          keep_pixels: int = 2_000_000, example: bool = False) -> Scored | None:
    """Score the traditional order, the filtered baseline and each model at (method, f).

    ``models``: {row name: checkpoint path or (net, ck)}. Returns None when the source has no
    data for the pair. ``example``: keep the first item's maps (for figures) under
    ``Scored.checks['example']``.
    """
    models = _models(models)
    pair = pair_at(method, f, ModelError)
    counts = {"Traditional": ErrorCount()}
    if filtered_window:
        counts[f"Filtered {filtered_window}x{filtered_window}"] = ErrorCount()
    counts.update({name: ErrorCount() for name in models})
    conf = {name: [] for name in models}
    wrong = {name: [] for name in models}
    checks: dict = {}
    n_items = 0
    for orientation in source.orientations:
        ds = source.dataset(method, f, orientation)
        if ds is None:
            continue
        widths = ds.ds.attrs.get("widths")
        width = float(widths[orientation]) if isinstance(widths, dict) and orientation in widths else None
        for i in range(len(ds)):
            item = ds[i]
            n_items += 1
            batch = torch.utils.data.default_collate([item])
            true = item["order_true"].numpy()
            valid = item["valid"].numpy()
            counts["Traditional"] += ErrorCount.of(item["order_traditional"].numpy(), true, valid)
            if filtered_window:
                k = filtered_order(method, item["phase_low"][0].numpy(), item["phase_high"][0].numpy(), pair, valid,
                                   window=filtered_window, width=width)
                counts[f"Filtered {filtered_window}x{filtered_window}"] += ErrorCount.of(k, true, valid)
            ex = {"traditional": item["order_traditional"].numpy(), "true": true, "valid": valid} \
                if example and "example" not in checks else None
            inputs = {}
            for name, (net, ck) in models.items():
                if name not in checks:
                    checks[name] = check_frequency_range(ck["meta"], method, pair, item["phase_high"][0].numpy(),
                                                         valid, on_outside="ignore")
                kind = ck["arch"]["kind"]
                if kind not in inputs:
                    inputs[kind] = make_inputs(batch, kind)
                order, c = predict(net, ck, batch, inputs[kind])
                order, c = order[0].numpy(), c[0].numpy()
                counts[name] += ErrorCount.of(order, true, valid)
                m = valid & (true >= 0)
                conf[name].append(c[m])
                wrong[name].append(order[m] != true[m])
                if ex is not None:
                    ex[name] = order
                    ex[name + " confidence"] = c
            if ex is not None:
                checks["example"] = ex
    if n_items == 0:
        return None
    rng = np.random.default_rng(0)
    for name in models:
        c, w = np.concatenate(conf[name]), np.concatenate(wrong[name])
        if c.size > keep_pixels:
            sel = rng.choice(c.size, keep_pixels, replace=False)
            c, w = c[sel], w[sel]
        conf[name], wrong[name] = c, w
    return Scored(counts, conf, wrong, checks, n_items)


def confidence_curve(scored: Scored, name: str, drops=DROPS):
    """[(fraction dropped, error rate kept)] of one model (least confident pixels dropped first)."""
    return keep_drop_curve(scored.confidence[name], scored.wrong[name], drops)


# ---------------------------------------------------------------- speed
def _time(fn, repeats: int) -> float:
    fn()
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best * 1e3


def speed_scene(size=(480, 640)):
    """(two 12-step uint8 stacks at 1 and 48 periods, their wrapped phases, modulations (fraction
    of full scale), valid mask) of a noisy linear ramp: the one orientation the speed rows time."""
    from unwrap.patterns import fringe_intensity
    from unwrap.phase_shift import wrapped_phase

    H, W = size
    rng = np.random.default_rng(0)
    u = np.tile(np.linspace(100, 800, W), (H, 1)) + rng.normal(0, 0.2, (H, W))
    Phi = {f: 2 * np.pi * f * u / 912 for f in (1, 48)}
    stacks = [np.clip(np.rint(255 * np.stack([fringe_intensity(Phi[f], n, 12, 0.5, 0.35) for n in range(12)])
                              + rng.normal(0, 2, (12, H, W))), 0, 255).astype(np.uint8) for f in (1, 48)]
    ws = [wrapped_phase(s) for s in stacks]
    return stacks, [np.nan_to_num(w.phase) for w in ws], [w.B / 255.0 for w in ws], ws[0].valid & ws[1].valid


def speed_table(model, *, size=(480, 640), repeats: int = 5, device: str = "cpu") -> dict:
    """Milliseconds per frame (minimum over ``repeats``) of one orientation, MF (1, 48), 12 steps:

    - ``traditional_from_phases``: mf_unwrap of two wrapped phases (the prior and the rounding);
    - ``traditional_from_frames``: the fused kernel from 2 x 12 uint8 frames (wrapped phases + MF);
    - ``filtered``: the 15x15 filtered baseline from the wrapped phases;
    - ``network_forward``: the network alone as the path runs it (the predictor
      :func:`unwrap.learned.runtime.load_predictor` makes of ``model``: for a checkpoint file on the
      CPU channels-last with BatchNorm folded, its input in that layout; ``forward_layout`` says
      which); ``learned_total``: prior + features + network + decode, with that predictor;
      ``whole_over_forward``: their ratio.
    """
    from unwrap.fused_mf import mf_unwrap_stacks
    from unwrap.temporal import mf_unwrap
    from unwrap.learned.infer import unwrap_learned
    from unwrap.learned.runtime import load_predictor

    pred = load_predictor(model, device)
    ck = pred.ck
    H, W = size
    stacks, phi, mods, valid = speed_scene(size)
    C, layout = int(ck["arch"]["in_channels"]), getattr(pred, "input_layout", "nchw")
    x = torch.zeros(1, H, W, C).permute(0, 3, 1, 2) if layout == "nhwc" else torch.zeros(1, C, H, W)
    x = x.to(device)
    out = {"size": f"{W}x{H}", "threads": torch.get_num_threads(), "device": device, "forward_layout": layout}
    out["traditional_from_phases_ms"] = _time(lambda: mf_unwrap(phi, (1, 48), width=912, valid=valid), repeats)
    out["traditional_from_frames_ms"] = _time(lambda: mf_unwrap_stacks(stacks, (1, 48), width=912), repeats)
    out["filtered_ms"] = _time(lambda: filtered_order("mf", phi[0], phi[1], (1, 48), valid, width=912), repeats)

    def fwd():
        pred.forward(x)
        if device != "cpu":
            torch.cuda.synchronize()
    out["network_forward_ms"] = _time(fwd, repeats)
    out["learned_total_ms"] = _time(lambda: unwrap_learned("mf", phi[0], phi[1], mods[0], mods[1], valid, (1, 48),
                                                           width=912, model=pred, on_outside="ignore"), repeats)
    out["whole_over_forward"] = out["learned_total_ms"] / out["network_forward_ms"]
    # what was timed computed the same thing: the fringe orders of the paths that should agree
    ref = mf_unwrap(phi, (1, 48), width=912, valid=valid, on_unreliable="ignore")
    fused = mf_unwrap_stacks(stacks, (1, 48), width=912).result
    learned = unwrap_learned("mf", phi[0], phi[1], mods[0], mods[1], valid, (1, 48), width=912, model=pred,
                             on_outside="ignore")
    both = np.asarray(ref.valid) & np.asarray(fused.valid)
    out["valid_pixels"] = int(both.sum())
    out["orders_frames_vs_phases"] = float(np.mean(np.asarray(fused.order)[both] == np.asarray(ref.order)[both]))
    lv = learned.valid & np.asarray(ref.valid)
    out["orders_learned_traditional_vs_phases"] = float(np.mean(learned.order_traditional[lv] == np.asarray(ref.order)[lv]))
    return out


def method_index(method: str) -> int:
    return METHOD_INDEX[method]
