"""The learned unwrapping's parity experiment: does the model trained on the twin behave on real
captures as on twin renders of the same system?

Data (both through ``unwrap.dataset``):

- real: capture datasets with reference orders (``synth.export.capture``; in ``../shared/data`` the
  one with a reference is SLStudio's skull: MF with 1 and 16 periods, 3 steps, 1688x1352, the
  reference from SLStudio's own Gray-code scan);
- twin: renders of the same system (its calibration, ``calib.load_system``) at the capture's steps
  and size, at the capture's frequency and at others (the model's training ratio 48 and the
  unseen 96), with the sensor noise matched to the capture's (:func:`capture_noise`).

Noise match: on the capture's valid pixels the traditional absolute phase ``phi + 2 pi k`` of the
high frequency is smooth (its 2 pi errors are outliers, moved by their whole turns before the plane
is refitted: :func:`experiments.plane_residual.order_outlier_residual`), so its residual from a 5x5
local plane (robust: 1.4826 x median absolute value, corrected for the fit's own degrees of
freedom) is its noise ``sigma_Phi``; with the N-step
noise gain, ``sigma_I = sigma_Phi * B * sqrt(N / 2)`` (full-scale units) per pixel, summarised by
its median. For the twin's Poisson sensor ``sigma_I^2 ~ I / full_well`` with ``I ~ B`` (full-contrast
fringes), so ``full_well = median(B) / sigma_I^2``. The twin renders are measured the same way and
both numbers are reported.

The section (verdict, table, figures) is laid out by :mod:`reports.learned_parity`.
"""
from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import torch

from .errors import ExperimentError

LOG = logging.getLogger("experiments")


def capture_noise(path, orientation: str = "v", pair=None) -> dict:
    """Sensor noise of a dataset file's high frequency (module docstring), on interior valid pixels.

    RETURNED VALUE: {"sigma_I": median full-scale intensity noise, "sigma_phase_rad": median
    phase noise, "modulation": median B (full scale), "pixels": pixels used, "steps": N}.
    """
    from unwrap.dataset import FringeOrderDataset
    from unwrap.dataset_schema import read_attrs
    from unwrap.reliability import plane_residual_noise
    import h5py

    from .plane_residual import order_outlier_residual

    with h5py.File(path, "r") as h5:
        a = read_attrs(h5)
    freqs = sorted(float(f) for f in a["frequencies"])
    pair = pair or (freqs[0], freqs[-1])
    steps = a["steps"]
    N = int(steps[freqs.index(pair[1])] if isinstance(steps, list) else steps)
    ds = FringeOrderDataset(path, method="mf", frequencies=pair, orientation=orientation, crop=None, seed=0)
    res, mods = [], []
    for i in range(len(ds)):
        it = ds[i]
        ok = it["valid"] & (it["order_traditional"] >= 0)
        if int(ok.sum()) < 100:
            continue
        # the traditional absolute phase: its rare 2 pi errors are outliers the median ignores
        Phi = (it["phase_high"][0].double() + 2 * math.pi * it["order_traditional"].double())[None, None]
        # residual of the pixel from the plane through its 5x5 neighbours (itself included), after
        # the orders of the neighbours are corrected (experiments.plane_residual)
        resid = order_outlier_residual(Phi[0, 0], ok)
        interior = ok & (torch.nn.functional.avg_pool2d(ok[None, None].double(), 5, 1, 2)[0, 0] > 0.999)
        res.append(resid[interior].numpy())
        mods.append(it["modulation_high"][0][interior].double().numpy())
    if not res:
        raise ExperimentError(f"{path}: no sample with reference orders to measure the noise on")
    noise = plane_residual_noise(np.concatenate(res), np.concatenate(mods), N)
    return {"sigma_I": noise["sigma_I"], "sigma_phase_rad": noise["sigma_phase_rad"],
            "modulation": noise["modulation"], "pixels": noise["pixels"], "steps": N, "pair": list(pair),
            "curve": noise_curve(np.concatenate(res), np.concatenate(mods), N)}


def noise_curve(residuals, modulation, steps: int, bins: int = 10, bits: int = 8) -> dict:
    """The intensity noise against modulation and the sensor it implies (:func:`capture_noise`'s
    plane residuals, rad, and modulations B, full scale, of the same pixels; ``steps`` N).

    Per decile of B, ``sigma_I`` as in :func:`unwrap.reliability.plane_residual_noise`; then the
    least-squares line ``sigma_I^2 = c0 + c1 B`` (shot noise with ``I ~ B`` plus a constant): full
    well ``1 / c1`` electrons, read noise ``sqrt(c0 - q^2) / c1`` electrons, ``q^2 = 1 / (12 (2^bits
    - 1)^2)`` the quantisation the renderer adds itself (0 where c0 is below it).
    RETURNED VALUE: {"modulation": [median B per bin], "sigma_I": [per bin], "full_well_e",
    "read_noise_e"} (full well and read noise None when the slope is not positive)."""
    from unwrap.reliability import plane_residual_noise

    e, B = np.asarray(residuals, np.float64).reshape(-1), np.asarray(modulation, np.float64).reshape(-1)
    edges = np.quantile(B, np.linspace(0.0, 1.0, bins + 1))
    xs, ys = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        s = (B >= lo) & (B <= hi)
        if s.sum() >= 100:
            r = plane_residual_noise(e[s], B[s], steps)
            xs.append(r["modulation"])
            ys.append(r["sigma_I"])
    c0, c1 = np.linalg.lstsq(np.vstack([np.ones(len(xs)), xs]).T, np.square(ys), rcond=None)[0]
    q2 = 1.0 / (12.0 * ((1 << bits) - 1) ** 2)
    ok = c1 > 0
    return {"modulation": [float(x) for x in xs], "sigma_I": [float(y) for y in ys],
            "full_well_e": float(1.0 / c1) if ok else None,
            "read_noise_e": float(math.sqrt(max(c0 - q2, 0.0)) / c1) if ok else None}


def _world_depths(system_file) -> tuple[float, float]:
    """Depth of the world origin in the camera and in the projector (mm): the export measures focus
    distances from these (``synth.export.scenes``); for a system whose world is the camera (SLStudio)
    they are 0 and ~the baseline, not the working distance."""
    from calib import load_system

    s = load_system(system_file)
    return float(s.camera.t[2]), float(s.projector.t[2])


def twin_config(system_file, full_well: float, *, mesh_dir, exposure=(0.45, 0.95), samples: int = 6, steps: int = 3,
                frequencies=(1, 16, 48, 96), depth_mm=(350, 450), size_mm=(100, 200), seed: int = 5,
                read_noise_e: float = 2.0):
    """The export config (``synth.export.config.ExportConfig``, built in memory) of twin renders of
    ``system_file`` with the matched noise and exposure: scene and effect ranges as the training
    set's, objects at the capture's working distance (``depth_mm`` from the world origin), both
    devices focused on it (+-50 mm); meshes from ``mesh_dir``; ``read_noise_e``: the sensor's read
    noise (electrons; :func:`capture_noise_curve` measures it on a capture)."""
    import tomli_w

    from synth.export.config import config_from_dict

    z_cam, z_prj = _world_depths(system_file)
    mid = 0.5 * (depth_mm[0] + depth_mm[1])
    f_cam = [mid - z_cam - 50, mid - z_cam + 50]
    f_prj = [mid - z_prj - 50, mid - z_prj + 50]
    tree = {
        "export": {"samples": int(samples), "seed": int(seed), "min_object_fraction": 0.05},
        "system": {"file": str(Path(system_file).resolve())},
        "patterns": {"orientations": ["v"], "frequencies": [float(f) for f in frequencies], "steps": int(steps)},
        "scene": {"objects": [1, 2], "mesh_dir": str(Path(mesh_dir).resolve()),
                  "meshes": ["cheburashka.obj", "suzanne.obj", "stanford-bunny.obj", "spot.obj"],
                  "mesh_fraction": 0.5, "procedural": ["sphere", "blobs", "heightfield"], "size_mm": list(size_mm),
                  "depth_mm": list(depth_mm), "background": 0.7, "background_gap_mm": [20, 120],
                  "background_tilt_deg": [0, 25], "albedo": [0.3, 0.95], "texture": 0.5,
                  "texture_contrast": [0.1, 0.6]},
        "effects": {"exposure": [round(float(e), 4) for e in exposure], "ambient": [0.0, 0.08],
                    "noise": {"full_well_e": round(float(full_well), 1), "read_noise_e": round(float(read_noise_e), 2)},
                    "projector_defocus": {"aperture_mm": [0, 3], "focus_offset_mm": [round(v, 1) for v in f_prj]},
                    "camera_defocus": {"aperture_mm": [0, 3], "focus_offset_mm": [round(v, 1) for v in f_cam]},
                    "global_illumination": {"subsurface": [0, 0.6], "scatter_mm": [0.5, 4], "interreflection": [0, 0.1],
                                            "interreflection_mm": [20, 60]},
                    "bits": 8},
        "output": {"codec": "gzip-1"},
    }
    return config_from_dict(tree, Path("."), tomli_w.dumps(tree), "matched twin")


def render_matched_twin(real_file, system_file, out_dir, *, mesh_dir, samples: int = 6,
                        frequencies=(1, 16, 48, 96), progress: bool = True) -> dict:
    """Measure the capture's noise, render the twin of ``system_file`` (synth; meshes from
    ``mesh_dir``) with the full well and exposure that match it, and measure the renders the same way.

    A 1-sample pilot (full well from ``synth.effects.sensor.shot_noise_full_well``, exposure 0.45-0.95) is
    measured; the exposure is then scaled by ``a = B_real / B_pilot`` (the export's light falloff
    is referenced to the world origin's distance, which differs between systems) and the full well
    by ``a (sigma_pilot / sigma_real)^2`` (shot noise: ``sigma_I^2 ~ I / full_well``) for the final
    render. The export configs are built in memory (:func:`twin_config`).
    RETURNED VALUE: {"file", "noise_real", "noise_twin", "full_well", "exposure", "pilot"}."""
    from synth.export.dataset import export_dataset
    from synth.effects.sensor import shot_noise_full_well

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    noise = capture_noise(real_file)
    pair = (1.0, float(noise["pair"][1]))

    def render(name, fw, exposure, n):
        path = out / f"{name}.h5"
        export_dataset(twin_config(system_file, fw, mesh_dir=mesh_dir, exposure=exposure, samples=n,
                                   steps=noise["steps"], frequencies=frequencies), path, progress=progress)
        return path, capture_noise(path, pair=pair)

    fw0, exp0 = shot_noise_full_well(noise["modulation"], noise["sigma_I"]), (0.45, 0.95)
    _, pilot = render("twin_pilot", fw0, exp0, 1)
    a = noise["modulation"] / max(pilot["modulation"], 1e-6)
    fw = fw0 * a * (pilot["sigma_I"] / noise["sigma_I"]) ** 2
    exposure = (exp0[0] * a, exp0[1] * a)
    LOG.info("learned parity: capture sigma_I %.4f, B %.3f; pilot twin (%.0f e-) sigma_I %.4f, B %.3f -> exposure "
             "x%.2f, full well %.0f e-", noise["sigma_I"], noise["modulation"], fw0, pilot["sigma_I"],
             pilot["modulation"], a, fw)
    path, twin = render("twin_parity", fw, exposure, samples)
    return {"file": str(path), "noise_real": noise, "noise_twin": twin, "full_well": fw,
            "exposure": list(exposure), "pilot": {"full_well": fw0, "exposure": list(exp0), "noise": pilot}}


def _score(files, pair, model) -> dict:
    from experiments.learned_evaluation import TestSource, score

    src = TestSource(files=[str(f) for f in files], orientations=("v", "h"))
    s = score(src, "mf", pair[1], {"learned": model}, filtered_window=15, example=True) if pair[0] == 1 else None
    if s is None:
        return {}
    return {"traditional": s.counts["Traditional"], "filtered": s.counts["Filtered 15x15"],
            "learned": s.counts["learned"], "example": s.checks.get("example"), "check": s.checks.get("learned"),
            "items": s.items}


def parity(real_files, twin_files, model="learned", *, frequencies=(16, 48, 96), pixel_twin_files=()) -> dict:
    """Error rates (traditional, filtered, learned) on the captures and the twin renders per frequency;
    ``pixel_twin_files`` (experiments.pixel_twin) add rows "pixel twin"."""
    from unwrap.learned.infer import resolve_model

    net = resolve_model(model)
    rows = []
    for f in frequencies:
        for kind, files in (("real", real_files), ("twin", twin_files), ("pixel twin", list(pixel_twin_files))):
            if not files:
                continue
            try:
                r = _score(files, (1.0, float(f)), net)
            except ValueError as exc:   # a frequency the file does not hold, a bad file
                LOG.info("learned parity: %s f=%g skipped: %s", kind, f, exc)
                r = {}
            if r and r["traditional"].counted:
                rows.append({"data": kind, "f": float(f), **{k: r[k] for k in ("traditional", "filtered", "learned")},
                             "items": r["items"], "example": r["example"], "check": r["check"]})
    return {"rows": rows, "model_meta": net[1]["meta"]}


def slstudio_parity(shared_data, out_dir, model="learned", *, samples: int = 2, progress: bool = True):
    """The whole parity experiment on SLStudio's skull (``shared_data`` = ``../shared/data``):
    export the capture with its Gray-code reference, render the matched twin and the pixel twin
    (:mod:`experiments.pixel_twin`, its sensor fitted on the capture), score all three.

    RETURNED VALUE: {"parity": :func:`parity`'s result, "twin": :func:`render_matched_twin`'s},
    or None when the capture is not there."""
    from synth.export.capture import export_capture

    root = Path(shared_data) / "slstudio-ps2x3-calib"
    skull, cloud = root / "skull_2x3", root / "skull_reference" / "pointCloud_from_skull_gray.mat"
    system = root / "calibration" / "calibration.xml"
    if not (skull.is_dir() and cloud.is_file() and system.is_file()):
        return None
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    real = out / "skull.h5"
    if not real.exists():
        export_capture(skull, real, reference_cloud=cloud, reference_system=system)
    twin = render_matched_twin(real, system, out, mesh_dir=Path(shared_data) / "meshes", samples=samples,
                               progress=progress)
    from .pixel_twin import capture_sensor, measure_capture, pixel_twin

    measured = measure_capture(real, skull)       # the frames and the top phase read once for both
    sensor = capture_sensor(real, skull, measured=measured)
    pix = [] if sensor["full_well_e"] is None else [pixel_twin(
        real, skull, out / "pixel_twin.h5", full_well_e=sensor["full_well_e"], read_noise_e=sensor["read_noise_e"],
        measured=measured)]
    twin["pixel_twin"] = {**(pix[0] if pix else {}), "sensor": sensor}
    return {"parity": parity([real], [twin["file"]], model, pixel_twin_files=[p["file"] for p in pix]), "twin": twin}
