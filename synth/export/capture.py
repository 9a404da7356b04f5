"""Real captures in the dataset schema (unwrap.dataset_schema, ``kind = "capture"``), so that the
model is evaluated on twin and real data through one reader.

``export_capture(DIR, OUT)`` turns any folder ``calib unwrap`` reads (or a folder of such folders,
one sample each, e.g. calibration poses) into one file: per orientation and frequency the
wrapped phase, modulation and flags of the captured frames (the same N-step least squares as the
twin export), and a *reference order* per frequency where the capture has one:

- ``gray``: the capture's own Gray code (SLMaster's complementary Gray code, kamino410's Gray
  blocks + beat), decoded by ``unwrap`` as ``calib unwrap --method gray`` does; the reference order
  of frequency f is ``round((Phi_ref f / f_top - phi_f) / 2 pi)``;
- ``cloud``: an independent point cloud of the same view (e.g. SLStudio's skull scanned with Gray
  code) projected into the projector with the capture's calibration: ``Phi_ref = 2 pi f u_p / W``;
- ``ladder``: a redundant MF ladder of the capture itself (three or more frequencies, e.g. 1 / 4 /
  16): the top frequency's order decoded step by step, kept where every frequency's modulation is
  high enough and every ladder step is decided with margin (unwrap.ladder_reference); only the top
  frequency carries it (the labelled pair is unit -> top), the others are -1;
- ``none``: no reference (``order_true`` is -1 everywhere, ``has_reference`` False).

``orientations`` keeps only some orientations (one file per orientation: each is a capture of
its own for a by-capture split); ``region`` ("left", "right", "top", "bottom") keeps one half of
the image: the other half is marked unlit with no reference, so two files of the two halves share
no pixel (a single capture split for fine-tuning and a held-out test).

A reference is kept at a pixel only where it is unambiguous: ``|Phi_ref - phi - 2 pi k| < pi/2``
(a quarter period of margin); the summary reports that margin's distribution and how often the
traditional decode agrees with the reference.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from unwrap.capture import check_distinct_frames, load_capture, read_stack
from unwrap.dataset_schema import (FLAG_LOW_MODULATION, FLAG_OUT_OF_RANGE, FLAG_SATURATED, MASK_LIT, MASK_SURFACE,
                                   SCHEMA, SCHEMA_VERSION, decode_phase, encode_modulation, encode_phase)
from unwrap.phase_shift import wrapped_phase

from .dataset import code_version
from .writer import ExportError, ShardWriter, fingerprint_of

TWO_PI = 2 * math.pi


def capture_folders(folder) -> list:
    """The capture folders under ``folder``: itself when it is a capture, else its sub-folders
    that are (sorted), e.g. one per calibration pose."""
    from unwrap.capture import detect_preset
    from unwrap.errors import UnwrapError

    folder = Path(folder)
    if not folder.is_dir():
        raise ExportError(f"--capture {folder}: not a folder")
    try:
        detect_preset(folder)
        return [folder]
    except UnwrapError:
        pass
    subs = []
    for d in sorted(p for p in folder.iterdir() if p.is_dir()):
        try:
            detect_preset(d)
            subs.append(d)
        except UnwrapError:
            continue
    if not subs:
        raise ExportError(f"--capture {folder}: neither a capture nor a folder of captures "
                          "(no capture.toml and no known scanner layout)")
    return subs


def _gray_reference(oc, sets, phases, valid):
    from unwrap.pipeline import unwrap_orientation

    r = unwrap_orientation(oc, "gray").result
    Phi = np.asarray(r.phase, dtype=np.float64)
    return Phi / r.frequency, np.asarray(r.valid) & valid


def _cloud_reference(system, cloud_xyz, oc, shape):
    """Absolute phase per period (Phi_ref / f = 2 pi c / width) from a point cloud (H, W, 3) mm."""
    prj = system.projector.without_skew_and_distortion()
    X = np.asarray(cloud_xyz, dtype=np.float64)
    if X.shape[:2] != tuple(shape):
        raise ExportError(f"reference cloud has {X.shape[:2]} pixels, the capture {tuple(shape)}")
    good = np.all(np.isfinite(X), axis=2) & (np.abs(X).sum(axis=2) > 0)
    q = np.full(X.shape[:2] + (2,), np.nan)
    q[good] = prj.project(X[good])
    c = q[..., 0] if oc.orientation == "v" else q[..., 1]
    return TWO_PI * c / oc.width, good & np.isfinite(c)


REGIONS = ("all", "left", "right", "top", "bottom")


def region_mask(shape, region: str) -> np.ndarray:
    """(H, W) bool: the pixels of ``region`` (one of :data:`REGIONS`; halves split at W // 2, H // 2)."""
    H, W = shape
    m = np.zeros((H, W), bool)
    sl = {"all": np.s_[:, :], "left": np.s_[:, : W // 2], "right": np.s_[:, W // 2:],
          "top": np.s_[: H // 2, :], "bottom": np.s_[H // 2:, :]}[region]
    m[sl] = True
    return m


def _ladder_ref(oc, sets, phases, mods, valid, ladder_opts):
    from unwrap.errors import UnwrapError
    from unwrap.ladder_reference import ladder_reference

    try:
        r = ladder_reference(phases, [s.frequency for s in sets], mods, width=oc.width, valid=valid, **ladder_opts)
    except UnwrapError as exc:
        raise ExportError(f"orientation {oc.orientation}: {exc}") from None
    return r.per_period, r.trusted, r.excluded


def _capture_sample(folder, preset, reference, cloud, system, orientations=None, region="all", ladder_opts=None):
    cap = load_capture(folder, preset)
    out, info = {}, {"folder": str(folder), "preset": cap.preset, "orientations": {}, "region": region}
    shape = None
    if orientations is not None:
        missing = [o for o in orientations if o not in cap.orientations]
        if missing:
            raise ExportError(f"{folder}: orientation(s) {missing} asked for, the capture has "
                              f"{sorted(cap.orientations)}")
    for o, oc in sorted(cap.orientations.items()):
        if orientations is not None and o not in orientations:
            continue
        sets = sorted(oc.sets, key=lambda s: s.frequency)
        if not sets:
            raise ExportError(f"{folder}: orientation {o} holds Gray code only (no phase-shift frames): there is "
                              "no wrapped phase to export")
        phases, mods, flags = [], [], []
        for s in sets:
            stack = read_stack(s.files)
            check_distinct_frames(stack, list(s.files))
            top = float(np.iinfo(stack.dtype).max) if np.issubdtype(stack.dtype, np.integer) else 1.0
            w = wrapped_phase(stack, s.shifts, min_modulation=0.02 * top)
            phases.append(np.where(w.valid, w.phase, np.nan))
            mods.append(w.B / top)
            flags.append((w.low_modulation * FLAG_LOW_MODULATION | w.saturated * FLAG_SATURATED
                          | w.out_of_range * FLAG_OUT_OF_RANGE).astype(np.uint8))
        shape = phases[0].shape
        valid = np.all([np.isfinite(p) for p in phases], axis=0) & region_mask(shape, region)
        ref_per_period, ref_ok, excluded = None, None, None
        kind = reference
        if kind == "auto":
            kind = "gray" if oc.gray is not None else ("cloud" if cloud is not None else "none")
        if kind == "gray":
            if oc.gray is None:
                raise ExportError(f"{folder}: reference 'gray' asked for, but the capture has no Gray code")
            ref_per_period, ref_ok = _gray_reference(oc, sets, phases, valid)
        elif kind == "cloud":
            if cloud is None or system is None:
                raise ExportError("reference 'cloud' needs reference_cloud and reference_system")
            ref_per_period, ref_ok = _cloud_reference(system, cloud, oc, shape)
        elif kind == "ladder":
            ref_per_period, ref_ok, excluded = _ladder_ref(oc, sets, phases, mods, valid, ladder_opts or {})
        refs = np.full((len(sets),) + shape, -1, np.int16)
        stats = {"reference": kind}
        if ref_per_period is not None:
            for j, s in enumerate(sets):
                if kind == "ladder" and j != len(sets) - 1:
                    continue   # only the top frequency: a reference at 4 of 1/4/16 would be circular
                ok = ref_ok & np.isfinite(phases[j]) & valid
                # relative to the phase as stored (int16; +pi is stored as -pi), which the reader decodes
                x = (ref_per_period * s.frequency - decode_phase(encode_phase(phases[j]))) / TWO_PI
                k = np.rint(x)
                margin = np.abs(x - k)
                keep = ok & (margin < 0.25) & (k >= 0) & (k <= math.floor(s.frequency + 0.5))
                refs[j] = np.where(keep, k, -1).astype(np.int16)
                stats[f"f{s.frequency:g}"] = {
                    "pixels_with_reference": int(keep.sum()), "valid_pixels": int(valid.sum()),
                    "margin_median_periods": float(np.median(margin[ok])) if ok.any() else None,
                    "margin_p99_periods": float(np.percentile(margin[ok], 99)) if ok.any() else None,
                    "dropped_ambiguous": int((ok & (margin >= 0.25)).sum())}
        if excluded is not None:
            stats["ladder_excluded"] = excluded
        out[o] = {"freqs": [s.frequency for s in sets], "steps": [len(s.files) for s in sets], "width": oc.width,
                  "phase": np.stack([encode_phase(p) for p in phases]),
                  "modulation": np.stack([encode_modulation(m) for m in mods]), "flags": np.stack(flags),
                  "reference_order": refs, "valid": valid}
        info["orientations"][o] = stats
    return out, info, shape


def export_capture(folder, out, *, preset=None, reference: str = "auto", reference_cloud=None,
                   reference_system=None, codec: str = "gzip-1", orientations=None, region: str = "all",
                   ladder_min_modulation: float = 0.02, ladder_max_step_residual: float = 0.2) -> dict:
    """Export the capture(s) in ``folder`` to ``out`` (see the module docstring).

    ``reference``: "auto" (Gray code when the capture has it, else the cloud when given, else
    none), "gray", "cloud", "ladder" or "none"; ``orientations``: None (all) or a list;
    ``region``: one of :data:`REGIONS`; ``ladder_*``: the trust thresholds of the ladder reference
    (unwrap.ladder_reference.ladder_reference); ``reference_cloud``: a .mat ('xyz', H x W x 3 mm) or .npy
    point cloud in the world frame of ``reference_system`` (anything calib.load_system reads).
    Returns a summary dict with the reference statistics per sample."""
    if reference not in ("auto", "gray", "cloud", "ladder", "none"):
        raise ExportError(f"reference {reference!r}: expected auto, gray, cloud, ladder or none")
    if region not in REGIONS:
        raise ExportError(f"region {region!r}: expected one of {REGIONS}")
    if orientations is not None:
        orientations = list(orientations)
        bad = [o for o in orientations if o not in ("v", "h")]
        if bad or not orientations:
            raise ExportError(f"orientations {orientations}: expected a non-empty list of 'v', 'h'")
    ladder_opts = {"min_modulation": ladder_min_modulation, "max_step_residual": ladder_max_step_residual}
    cloud = system = None
    if reference_cloud is not None:
        p = Path(reference_cloud)
        if p.suffix == ".mat":
            from scipy.io import loadmat
            cloud = loadmat(str(p))["xyz"]
        else:
            cloud = np.load(p)
        from calib.io import load_system
        if reference_system is None:
            raise ExportError("reference_cloud needs reference_system (the calibration of the capture)")
        system = load_system(reference_system)
    folders = capture_folders(folder)
    samples, infos = [], []
    for f in folders:
        arrays, info, shape = _capture_sample(f, preset, reference, cloud, system, orientations, region, ladder_opts)
        samples.append((arrays, shape))
        infos.append(info)
    first, shape = samples[0]
    orients = sorted(first)
    for (arr, shp), f in zip(samples[1:], folders[1:]):
        if sorted(arr) != orients or shp != shape or any(arr[o]["freqs"] != first[o]["freqs"] for o in orients):
            raise ExportError(f"{f}: other orientations, frequencies or image size than {folders[0]}")
    freqs = sorted({f for o in orients for f in first[o]["freqs"]})
    H, W = shape
    attrs = {"schema": SCHEMA, "schema_version": SCHEMA_VERSION, "kind": "capture", "orientations": orients,
             "frequencies": [float(x) for x in freqs], "steps": first[orients[0]]["steps"],
             "widths": json.dumps({o: first[o]["width"] for o in orients}), "camera_size": [W, H], "bits": 8,
             "min_modulation": 0.02, "system": "", "config": json.dumps({"capture": str(folder), "reference": reference,
                                                                        "reference_cloud": str(reference_cloud),
                                                                        "orientations": orientations, "region": region,
                                                                        "ladder": ladder_opts if reference == "ladder" else None}),
             "seed": 0, "code_version": code_version(), "codec": codec, "samples_total": len(folders),
             "shard": [0, 1], "units": "px, rad"}
    attrs["fingerprint"] = fingerprint_of(attrs["config"], [str(f) for f in folders])
    groups = {o: {"frequencies": [float(x) for x in first[o]["freqs"]], "steps": first[o]["steps"]} for o in orients}
    writer = ShardWriter(out, range(len(folders)), attrs, codec, attrs["fingerprint"], groups)
    if writer.complete():
        return {"file": str(out), "samples": len(folders), "captures": infos}
    writer.prepare()
    for i, ((arr, _), info) in enumerate(zip(samples, infos)):
        valid = np.any([arr[o]["valid"] for o in orients], axis=0)
        arrays = {"masks": (valid * (MASK_SURFACE | MASK_LIT)).astype(np.uint8)}
        for o in orients:
            for k in ("phase", "modulation", "flags", "reference_order"):
                arrays[f"{o}/{k}"] = arr[o][k]
        writer.write_part(i, arrays, json.dumps(info), np.full((len(orients), max(len(first[o]["freqs"]) for o in orients), 4), -1, np.int32))
    writer.assemble()
    return {"file": str(out), "samples": len(folders), "captures": infos}
