"""Fit the traditional decision's error model (:mod:`unwrap.decision_error`) on twin validation scenes.

    python -m bench.decision_error_fit [--work DIR] [--json OUT.json] [--quick] [--global]

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
``--work`` (one ``.npz`` per scene; ~1-6 min a scene on 2 shared cores). The scene and fit code
lives in :mod:`bench.spatial_unwrap` (``bias_items``, ``fit_items``), which refits the model
with ``--calibrate`` / ``--calibrate-gate``.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from unwrap.safe_output import write_text


def main(argv=None) -> int:
    from bench.spatial_unwrap import _twin_items, bias_items, fit_items

    ap = argparse.ArgumentParser(prog="python -m bench.decision_error_fit", description=__doc__.split("\n")[0])
    ap.add_argument("--work", default="/tmp/sltwin_bench_spatial", help="cache of the renders")
    ap.add_argument("--json", default=None)
    ap.add_argument("--quick", action="store_true", help="one bias scene only (no export): a smoke run, not the fit")
    ap.add_argument("--global", dest="global_", action="store_true",
                    help="fit MODEL_GLOBAL: the global / direct ratio (unwrap.global_light) as a sixth feature (the "
                         "scenes' offsets are rendered into --work; bench.global_bias)")
    args = ap.parse_args(argv)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    if args.global_:
        from bench.global_bias import fit_global, twin_items
        items = bias_items(work, limit=1) if args.quick else bias_items(work) + twin_items(work, "val")
        model = fit_global(items)
        print("MODEL_GLOBAL = " + json.dumps(model))
    else:
        items = bias_items(work, limit=1) if args.quick else _twin_items(work, "val") + bias_items(work)
        model = fit_items(items)
        print("MODEL = " + json.dumps(model))
    if args.json:
        write_text(Path(args.json), json.dumps(model, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
