"""A twin of a real capture built from what the capture measures, pixel by pixel (issue 21: "twin
vs real traditional error on the SLStudio skull within 1.5x").

The capture's own frames give, per pixel and frequency, the background ``A`` and modulation ``B``
(full scale, N-step least squares) - exposure, albedo, shading, contrast and any ambient light
as the camera saw them; its reference orders (e.g. SLStudio's Gray-code cloud through SLStudio's
calibration, :mod:`synth.export.capture`) give the geometry. The twin replaces only the noise:

    I_n = A + B cos(Phi_f - delta_n),    Phi_f = Phi_top f / f_top      (rad, full scale)

then Poisson-Gaussian noise of the sensor fitted on the capture (:func:`sensor_fit`), 8-bit
quantisation (``synth.effects.sensor``), and the same decode as the capture's export
(``unwrap.phase_shift.wrapped_phase`` with the export's modulation threshold). ``Phi_top`` is the
capture's absolute phase of its top frequency (the reference order where there is one, the
traditional order elsewhere), order outliers moved by their whole turns and smoothed by the 5x5
plane (:func:`experiments.plane_residual.order_outlier_residual`), so that its noise is not
counted twice. The twin's reference order is that of ``Phi_f`` against its own stored wrapped
phase, kept on the capture's labelled pixels only, with the export's quarter-period margin: the
same masks and reference as the real file, one noise draw per ``seed``.

What it does not hold, by construction: any phase bias of the real capture (projector / camera
response, the unit pattern's phase against the top one, interreflection, defocus across edges)
- a real-to-twin ratio above 1 measures those; the noise model is the only physics added.

Sensor (:func:`sensor_fit`): the capture's plane residuals (:func:`experiments.learned_parity.capture_noise`'s
estimator) per decile of the background ``A``, ``sigma_I^2 = c0 + c1 A`` (shot noise grows with
the light a pixel collects, ``A``, not with ``B``; the two differ by the contrast ``B / A``):
full well ``1 / c1`` electrons, read noise ``sqrt(c0 - q^2) / c1`` electrons.
"""
from __future__ import annotations

import math
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import ExperimentError

TWO_PI = 2 * math.pi


def capture_fringes(folder, orientation: str = "v") -> list:
    """The capture's fringe sets of one orientation, by frequency: [{"frequency", "shifts" (N,) rad,
    "A", "B", "phase" (H, W) float64 full scale / rad, "top" (the frames' full-scale count)}]."""
    from unwrap.capture import load_capture, read_stack
    from unwrap.phase_shift import wrapped_phase

    cap = load_capture(folder)
    if orientation not in cap.orientations:
        raise ExperimentError(f"{folder}: no orientation {orientation!r} (has {sorted(cap.orientations)})")
    out = []
    for s in sorted(cap.orientations[orientation].sets, key=lambda s: s.frequency):
        stack = read_stack(s.files)
        top = float(np.iinfo(stack.dtype).max) if np.issubdtype(stack.dtype, np.integer) else 1.0
        w = wrapped_phase(stack, s.shifts, min_modulation=0.02 * top)
        out.append({"frequency": float(s.frequency), "shifts": np.asarray(s.shifts, np.float64),
                    "A": np.asarray(w.A, np.float64) / top, "B": np.asarray(w.B, np.float64) / top,
                    "phase": np.asarray(w.phase, np.float64), "top": top})
    return out


def _absolute_top(real_file, orientation: str):
    """Sample 0 of a capture file: (Phi_top (H, W) rad with the reference order where there is one
    and the traditional elsewhere, its order outliers moved by their whole turns, its residual from
    the 5x5 plane (``Phi_top - residual`` is the plane: no 2 pi spike where an order was moved), the
    decoded pixels, the labelled pixels, the reference orders (F, H, W), the frequencies)."""
    import h5py
    import torch

    from unwrap.dataset import FringeOrderDataset
    from unwrap.dataset_schema import read_attrs

    from .plane_residual import order_outlier_fit

    with h5py.File(real_file, "r") as h5:
        a = read_attrs(h5)
        ref = h5[f"{orientation}/reference_order"][0].astype(np.int64)
    freqs = sorted(float(f) for f in a["frequencies"])
    ds = FringeOrderDataset(real_file, method="mf", frequencies=(freqs[0], freqs[-1]), orientation=orientation,
                            crop=None, seed=0)
    it = ds[0]
    k_trad = it["order_traditional"].numpy().astype(np.int64)
    lab = it["order_true"].numpy() >= 0
    ok = it["valid"].numpy() & (k_trad >= 0)
    k = np.where(lab, it["order_true"].numpy(), k_trad)
    Phi = it["phase_high"][0].double().numpy() + TWO_PI * k
    Phi, r = (x.numpy() for x in order_outlier_fit(torch.from_numpy(Phi), torch.from_numpy(ok)))
    return Phi, r, ok, lab, ref, freqs


@dataclass(frozen=True)
class CaptureMeasure:
    """What :func:`capture_sensor`, :func:`pixel_twin` and :func:`unit_phase_bias` read from a capture,
    measured once (:func:`measure_capture`): ``sets`` (:func:`capture_fringes`'s list, None when no
    frames folder was given) and :func:`_absolute_top`'s ``Phi``, ``r``, ``ok``, ``lab`` (H, W),
    ``ref`` (F, H, W), ``freqs`` of the export ``real_file``. Read only: the functions copy
    before they change anything."""
    real_file: str
    folder: str | None
    orientation: str
    sets: list | None
    Phi: np.ndarray
    r: np.ndarray
    ok: np.ndarray
    lab: np.ndarray
    ref: np.ndarray
    freqs: list


def measure_capture(real_file, folder=None, orientation: str = "v") -> CaptureMeasure:
    """Read a capture once for the functions of this module: the export ``real_file``'s absolute top
    phase and masks (:func:`_absolute_top`, ~10 s at 1688x1352 on 2 cores) and, when ``folder`` is
    given, its frames' A, B and phases (:func:`capture_fringes`)."""
    sets = None if folder is None else capture_fringes(folder, orientation)
    return CaptureMeasure(str(real_file), None if folder is None else str(folder), orientation, sets,
                          *_absolute_top(real_file, orientation))


def _measured(real_file, folder, orientation: str, measured: CaptureMeasure | None, frames: bool) -> CaptureMeasure:
    """``measured`` checked against the arguments, or a fresh :func:`measure_capture`."""
    if measured is None:
        return measure_capture(real_file, folder if frames else None, orientation)
    if Path(measured.real_file).resolve() != Path(real_file).resolve() or (
            frames and Path(measured.folder).resolve() != Path(folder).resolve()):
        raise ExperimentError(f"{real_file}: the measurement given is of {measured.real_file} ({measured.folder})")
    if measured.orientation != orientation or (frames and measured.sets is None):
        raise ExperimentError(f"{real_file}: the measurement given is of orientation {measured.orientation!r}"
                              f"{'' if measured.sets is not None else ', without frames'}; needed {orientation!r}"
                              f"{' with frames' if frames else ''}")
    return measured


def sensor_fit(residuals, A, B, steps: int, bins: int = 10, bits: int = 8) -> dict:
    """Intensity noise against the background ``A`` and the Poisson-Gaussian sensor it implies
    (module docstring). ``residuals`` (rad): the top frequency's plane residuals of the same pixels
    as ``A`` and ``B`` (full scale).

    RETURNED VALUE: {"A": [median A per decile], "sigma_I": [per decile], "full_well_e",
    "read_noise_e"} (None when the slope is not positive)."""
    from unwrap.reliability import plane_residual_noise

    e, A, B = (np.asarray(x, np.float64).reshape(-1) for x in (residuals, A, B))
    edges = np.quantile(A, np.linspace(0.0, 1.0, bins + 1))
    xs, ys = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        s = (A >= lo) & (A <= hi)
        if s.sum() >= 100:
            xs.append(float(np.median(A[s])))
            ys.append(plane_residual_noise(e[s], B[s], steps)["sigma_I"])
    if len(xs) < 2:
        raise ExperimentError("sensor_fit: fewer than two bins of >= 100 pixels")
    c0, c1 = np.linalg.lstsq(np.vstack([np.ones(len(xs)), xs]).T, np.square(ys), rcond=None)[0]
    q2 = 1.0 / (12.0 * ((1 << bits) - 1) ** 2)
    ok = c1 > 0
    return {"A": xs, "sigma_I": [float(y) for y in ys], "full_well_e": float(1.0 / c1) if ok else None,
            "read_noise_e": float(math.sqrt(max(c0 - q2, 0.0)) / c1) if ok else None}


def capture_sensor(real_file, folder, orientation: str = "v", *, measured: CaptureMeasure | None = None) -> dict:
    """:func:`sensor_fit` on a capture: the export ``real_file`` (orders) and its frames ``folder``
    (A, B of the top frequency), on the interior valid pixels (all 25 of the 5x5 window valid).
    ``measured``: :func:`measure_capture` of the same files, when the caller already has it."""
    import torch

    m = _measured(real_file, folder, orientation, measured, True)
    sets, r, ok = m.sets, m.r, m.ok
    interior = ok & (torch.nn.functional.avg_pool2d(torch.from_numpy(ok)[None, None].double(), 5, 1, 2)[0, 0].numpy()
                     > 0.999)
    top = sets[-1]
    fit = sensor_fit(r[interior], top["A"][interior], top["B"][interior], len(top["shifts"]))
    fit["contrast_median"] = float(np.median(top["B"][interior] / np.maximum(top["A"][interior], 1e-9)))
    return fit


def unit_phase_bias(real_file, orientation: str = "v", window: int = 15, leave_one_out: bool = False, *,
                    measured: CaptureMeasure | None = None) -> dict:
    """The capture's coherent bias of the unit phase against its top frequency's:
    ``d = wrap(phi_1 - Phi_top / f_top)`` on the labelled pixels (Phi_top as in :func:`pixel_twin`:
    reference orders, 5x5 plane), averaged over ``window`` x ``window`` boxes (kept where a
    quarter of the box is labelled, else 0; ``leave_one_out``: the box without the pixel itself).
    Noise averages out of the box mean (~0.027 rad per pixel on the skull, ~100 pixels per 15x15
    box; a small box keeps some: ~0.01 rad at 5x5); what is left is a bias the order decision sees
    ``f_top`` times: ``16 d`` at MF 1 -> 16.

    RETURNED VALUE: {"bias" (H, W) rad, "rms" of the map over the labelled pixels, "pixel_sd" the
    robust spread of ``d - bias`` (the noise), "labelled" (H, W) bool}. ``measured``:
    :func:`measure_capture` of ``real_file`` (frames not needed), when the caller already has it."""
    import cv2

    m = _measured(real_file, None, orientation, measured, False)
    Phi, r, lab, freqs = m.Phi, m.r, m.lab, m.freqs
    import h5py

    from unwrap.dataset_schema import decode_phase

    with h5py.File(real_file, "r") as h5:
        phi1 = decode_phase(h5[f"{orientation}/phase"][0, 0])
    d = np.where(lab, np.angle(np.exp(1j * (phi1 - (Phi - r) * (freqs[0] / freqs[-1])))), 0.0)
    n = cv2.boxFilter(lab.astype(np.float64), -1, (window, window), normalize=False)
    s = cv2.boxFilter(d, -1, (window, window), normalize=False)
    if leave_one_out:   # a pixel's bias from its neighbours only: its own deviation (noise) is not in it
        n, s = n - lab, s - d
    keep = n > max(window * window / 4.0 - 1.0, 1.0)
    b = np.where(keep, s / np.maximum(n, 1.0), 0.0)
    m = lab & keep
    return {"bias": b, "rms": float(np.sqrt(np.mean(b[m] ** 2))) if m.any() else 0.0,
            "pixel_sd": float(1.4826 * np.median(np.abs((d - b)[m]))) if m.any() else 0.0, "labelled": lab}


def pixel_twin(real_file, folder, out_file, *, full_well_e: float, read_noise_e: float, seed: int = 0,
               orientation: str = "v", bits: int = 8, unit_bias=None, measured: CaptureMeasure | None = None) -> dict:
    """Write the pixel twin of ``real_file`` (a capture export with reference orders; its frames
    in ``folder``) to ``out_file`` (module docstring): a copy of the real file whose phase,
    modulation, flags and reference orders of ``orientation`` are the twin's. ``unit_bias`` (H, W)
    rad, optional: added to the lowest frequency's rendered phase only (e.g.
    :func:`unit_phase_bias`'s map); the reference orders stay those of the unbiased phase.
    ``measured``: :func:`measure_capture` of the same files, when the caller already has it (the
    capture's frames and top phase are then not read again; the file written is the same).

    RETURNED VALUE: {"file", "labelled": [per frequency, real], "labelled_twin": [per frequency],
    "seed", "full_well_e", "read_noise_e"}."""
    import h5py
    import torch

    from synth.effects.sensor import add_noise, quantise
    from synth.effects.spec import Noise
    from unwrap.dataset_schema import decode_phase, encode_modulation, encode_phase
    from unwrap.dataset_schema import FLAG_LOW_MODULATION, FLAG_OUT_OF_RANGE, FLAG_SATURATED
    from unwrap.phase_shift import wrapped_phase
    from unwrap.safe_output import atomic_path

    m = _measured(real_file, folder, orientation, measured, True)
    sets, Phi, r, ok, ref, freqs = m.sets, m.Phi, m.r, m.ok, m.ref, m.freqs
    if [s["frequency"] for s in sets] != freqs:
        raise ExperimentError(f"{folder}: frequencies {[s['frequency'] for s in sets]} differ from {real_file}'s {freqs}")
    Phi_top = np.where(ok, Phi - r, np.nan)        # the 5x5 plane through the corrected orders
    gen = torch.Generator().manual_seed(int(seed))
    top_count = float((1 << bits) - 1)
    phases, mods, flags, refs = [], [], [], []
    for j, s in enumerate(sets):
        Phi_f = Phi_top * (s["frequency"] / freqs[-1])
        A, B = s["A"], s["B"]
        live = ok & np.isfinite(A) & np.isfinite(B)
        shown = Phi_f + unit_bias if (unit_bias is not None and j == 0) else Phi_f
        I = A[None] + B[None] * np.cos(np.where(live, shown, 0.0)[None] - s["shifts"][:, None, None])
        I = torch.from_numpy(np.where(live[None], I, 0.0).astype(np.float32)).contiguous()
        counts = quantise(add_noise(I, Noise(full_well_e, read_noise_e, int(seed)), gen), bits).numpy()
        w = wrapped_phase(counts, s["shifts"], min_modulation=0.02 * top_count)
        ph = np.where(w.valid & live, w.phase, np.nan)
        phases.append(encode_phase(ph))
        mods.append(encode_modulation(np.asarray(w.B) / top_count))
        flags.append((w.low_modulation * FLAG_LOW_MODULATION | w.saturated * FLAG_SATURATED
                      | (w.out_of_range | ~live) * FLAG_OUT_OF_RANGE).astype(np.uint8))
        # the twin's truth against its own stored phase; the real file's labelled pixels and margin rule
        x = (Phi_f - decode_phase(phases[-1])) / TWO_PI
        k = np.rint(np.nan_to_num(x, nan=-1.0))
        keep = (ref[j] >= 0) & np.isfinite(ph) & (np.abs(x - k) < 0.25) & (k >= 0) & \
            (k <= math.floor(s["frequency"] + 0.5))
        refs.append(np.where(keep, k, -1).astype(np.int16))
    out = Path(out_file)
    with atomic_path(out) as tmp:      # unwrap.safe_output: renamed onto out only when complete
        shutil.copyfile(real_file, tmp)
        with h5py.File(tmp, "r+") as h5:
            for name, arr in (("phase", phases), ("modulation", mods), ("flags", flags), ("reference_order", refs)):
                h5[f"{orientation}/{name}"][0] = np.stack(arr)
            h5.attrs["pixel_twin"] = (f"pixel twin of {Path(real_file).name}: capture A, B; sensor {full_well_e:.0f} e- "
                                      f"full well, {read_noise_e:.1f} e- read noise, seed {int(seed)}; unit bias "
                                      f"{'none' if unit_bias is None else 'given'}")
    return {"file": str(out), "labelled": [int((x >= 0).sum()) for x in ref],
            "labelled_twin": [int((x >= 0).sum()) for x in refs], "seed": int(seed),
            "full_well_e": float(full_well_e), "read_noise_e": float(read_noise_e)}
