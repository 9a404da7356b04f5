"""Fit the traditional decision's error model (:mod:`unwrap.decision_error`) on twin validation scenes.

    python -m bench.decision_error_fit [--work DIR] [--json OUT.json] [-q]

Scenes (validation only, never a held-out mesh or a real capture):

- ``bench/data/spatial_val.toml`` (the gate's calibration set: noisy and clean 12-step scenes,
  the old screen-space interreflection term; noise-dominated errors), exported by ``calib export``;
- ``bench/data/decision_error_val.toml`` (training meshes a few mm to cm before a wall, high-SNR
  12-step captures, defocus, subsurface) rendered here with the physically based one-bounce
  interreflection of :mod:`synth.effects.interreflection` (mesh visibility on): the coherent
  bias of the unit phase along outlines and beside cast shadows that real captures show.

Both are decoded as :mod:`bench.spatial_unwrap` decodes them (MF 1 -> 48, the traditional
prior rounded, the noise model's error probability with the shipped ``sigma_floor``); the
features of :func:`unwrap.decision_error.features` and the labels (traditional order != the
geometric order) are pooled and :func:`unwrap.decision_error.fit` fits the model. The printed
``MODEL = {...}`` is what :data:`unwrap.decision_error.MODEL` holds. Renders are cached in
``--work`` (one ``.npz`` per scene; ~1-3 min a scene on 2 shared cores).
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
BIAS_CONFIG = ROOT / "bench" / "data" / "decision_error_val.toml"


def _render_bias_scene(cfg, system, index: int) -> dict:
    """One bias scene of ``cfg`` (export config) with physical interreflection, reduced to a
    bench item's arrays (the pair's wrapped phases, modulations in full scale, valid, the geometric
    order of the high frequency)."""
    from synth.effects.spec import Interreflection
    from synth.renderer.geometry import compute_geometry
    from synth.renderer.render import render
    from synth.export.scenes import draw_scene
    from unwrap._xp import TWO_PI, round_order
    from unwrap.phase_shift import wrapped_phase
    from unwrap.reliability import fit_noise_sigma

    W, H = system.camera.size
    Wp, _ = system.projector.size
    for attempt in range(cfg.max_redraws):
        rng = np.random.default_rng([cfg.seed, index, attempt])
        scene, params = draw_scene(cfg, system, rng)
        geom = compute_geometry(scene)
        n_obj = len(params.get("objects", []))
        covered = float(((geom.object_id < n_obj) & (geom.object_id >= 0) & geom.lit).sum()) / (W * H)
        if covered >= cfg.min_object_fraction:
            break
    else:
        raise RuntimeError(f"bias scene {index}: objects cover too little of the image")
    scene = replace(scene, effects=replace(scene.effects, interreflection=Interreflection()))
    res = render(scene, geometry=geom)
    top = float((1 << res.bits) - 1)
    names = {n: k for k, n in enumerate(res.names)}
    imgs = res.images.numpy().astype(np.float64)
    lit = geom.lit.reshape(H, W).numpy()
    w, stacks = {}, {}
    for f in cfg.frequencies:
        stacks[f] = imgs[[names[p.name] for p in scene.patterns if p.frequency == f]]
        w[f] = wrapped_phase(stacks[f], min_modulation=cfg.min_modulation * top, saturation=top)
    f_lo, f_hi = cfg.frequencies[0], cfg.frequencies[-1]
    valid = lit & w[f_lo].valid & w[f_hi].valid
    phi_hi = np.nan_to_num(w[f_hi].phase)
    Phi = TWO_PI * f_hi * np.nan_to_num(geom.u_p.reshape(H, W).numpy().astype(np.float64)) / Wp
    ref = np.where(valid, round_order((Phi - phi_hi) / TWO_PI), -1).astype(np.int64)
    sigma = fit_noise_sigma(stacks[f_hi], None, valid) / top
    return dict(phase_low=np.nan_to_num(w[f_lo].phase), phase_high=phi_hi, m_low=w[f_lo].B / top,
                m_high=w[f_hi].B / top, valid=valid, ref=ref, freqs=(float(f_lo), float(f_hi)), width=float(Wp),
                steps=int(cfg.steps[-1]), sigma_I=float(sigma))


def bias_items(work: Path, *, progress: bool = True) -> list:
    """The bias scenes as :mod:`bench.spatial_unwrap` items, rendered once and cached in ``work``."""
    from synth.export.config import load_config
    from synth.export.dataset import base_system

    cfg = load_config(BIAS_CONFIG)
    system, _ = base_system(cfg)
    items = []
    for i in range(cfg.samples):
        path = work / f"bias_val_{cfg.seed}_{i}.npz"
        if not path.exists():
            if progress:
                print(f"rendering bias scene {i + 1}/{cfg.samples} (interreflection) -> {path}", file=sys.stderr,
                      flush=True)
            it = _render_bias_scene(cfg, system, i)
            tmp = path.with_name(path.name + ".tmp.npz")
            np.savez_compressed(tmp, **it)
            tmp.replace(path)
        z = np.load(path)
        it = {k: z[k] for k in z.files}
        for k in ("width", "sigma_I"):
            it[k] = float(it[k])
        it["steps"], it["freqs"] = int(it["steps"]), tuple(float(f) for f in it["freqs"])
        it["name"] = f"twin bias-val v #{i}"
        items.append(it)
    return items


def item_features(it, sigma_floor: float | None = None):
    """(features (N, K), wrong (N,) bool, p_model (H, W)) of one item's valid pixels with a reference."""
    from unwrap.decision_error import error_probability, features
    from unwrap.spatial_orders import DEFAULTS, phase_noise, prior_sigma, traditional_error_probability
    from unwrap.temporal import decode_pair

    sf = DEFAULTS["sigma_floor"] if sigma_floor is None else sigma_floor
    prior, n, ok = decode_pair("mf", it["phase_low"], it["phase_high"], *it["freqs"], it["width"], it["valid"])
    s_lo = phase_noise(it["m_low"], it["steps"], it["sigma_I"])
    s_hi = phase_noise(it["m_high"], it["steps"], it["sigma_I"])
    sig = np.sqrt(prior_sigma("mf", it["freqs"], s_lo, s_hi) ** 2 + sf ** 2)
    p_noise = traditional_error_probability(prior, n, sig, ok)
    X = features(p_noise, prior, ok, it["m_low"], it["m_high"])
    m = ok & (it["ref"] >= 0)
    return X[m], (n != it["ref"])[m], error_probability(p_noise, prior, ok, it["m_low"], it["m_high"])


def fit_items(items) -> dict:
    """Pooled fit over the items (module docstring); the model dict of :mod:`unwrap.decision_error`."""
    from unwrap.decision_error import fit

    Xs, ys = [], []
    for it in items:
        X, y, _ = item_features(it)
        Xs.append(X), ys.append(y)
    X, y = np.concatenate(Xs), np.concatenate(ys)
    print(f"  decision error model: {len(y):,} pixels, {int(y.sum()):,} traditional errors "
          f"({100 * y.mean():.3f} %)", file=sys.stderr)
    return fit(X, y, note=f"bench.decision_error_fit: {len(items)} validation scenes "
                          f"(spatial_val.toml + decision_error_val.toml with interreflection), {len(y)} pixels")


def validation_items(work: Path) -> list:
    """Every validation item (the gate's calibration set and the bias scenes)."""
    from bench.spatial_unwrap import _twin_items
    return _twin_items(work, "val") + bias_items(work)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.decision_error_fit", description=__doc__.split("\n")[0])
    ap.add_argument("--work", default="/tmp/sltwin_bench_spatial", help="cache of the renders")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    model = fit_items(validation_items(work))
    print("MODEL = " + json.dumps(model))
    if args.json:
        out = Path(args.json)
        tmp = out.with_name(out.name + ".tmp")
        tmp.write_text(json.dumps(model, indent=1))
        tmp.replace(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
