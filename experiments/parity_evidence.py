"""The numbers behind docs/learned.md's skull parity section, each from a stated definition (issue
21 item 8: "honest parity"), printed by ``python -m bench.skull_parity``.

Every function has an array core (testable on synthetic data) and reads files only through
:mod:`experiments.pixel_twin`'s :class:`~experiments.pixel_twin.CaptureMeasure` or
``unwrap.dataset``. Phases in rad, modulation ``B`` and background ``A`` in full scale (0-1),
distances in camera pixels (centre to centre, Euclidean). A *labelled* pixel has a reference
order; a *wrong* one is labelled with ``traditional order != reference order`` (MF from the unit
to the top frequency); an *invalid* pixel is one the MF decode does not keep (``valid`` false:
shadow, background, low modulation, saturation).

- :func:`error_places`: where the wrong pixels are (connected components, distance to the nearest
  invalid pixel, modulation);
- :func:`reference_suspects`: which wrong pixels look like errors of the *reference*: the plane
  through the absolute top phase of the pixel's ``window`` x ``window`` neighbours (those whose
  orders agree, so no error is in it) predicts an order; if it is the traditional one, the
  reference, not the decode, is the odd one out;
- :func:`gamma_bias` / :func:`fit_gamma`: the power-law response ``gamma`` (projector intensity
  ``((1 + cos(u - delta_n)) / 2) ** gamma``) that best explains the unit phase's deviation from
  the top phase, as a function of the unit phase itself;
- :func:`error_coincidence`: how many of a twin's wrong pixels lie within ``radius`` of a real
  wrong pixel, against the share of labelled pixels that do (chance);
- :func:`noise_match`: the pixel twin's noise against the capture's (per decile of ``A``, the plane
  residual estimator of both) and against its own sensor (per decile of ``B``, the twin's true
  phase error vs ``sqrt(2 / N) sigma_I / B``).
"""
from __future__ import annotations

import math

import numpy as np

from .errors import ExperimentError

TWO_PI = 2 * math.pi


def _within(mask, radius: float):
    """(H, W) bool: pixels within ``radius`` px (Euclidean) of a True pixel of ``mask`` (H, W)."""
    import cv2

    if not mask.any():
        return np.zeros(mask.shape, bool)
    d = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return d <= radius


def error_places(wrong, labelled, valid, modulation, *, radius: float = 5.0, low_modulation: float = 0.05) -> dict:
    """Where the wrong pixels (H, W) bool are, among the ``labelled`` and ``valid`` ones (H, W) bool;
    ``modulation`` (H, W) the top frequency's B.

    RETURNED VALUE: {"wrong", "labelled", "components" (8-connected), "largest" (px),
    "near_invalid" (wrong pixels within ``radius`` of an invalid pixel), "labelled_near_invalid"
    (fraction of the labelled pixels there), "median_B_wrong", "median_B_labelled", "low_B_labelled"
    (labelled pixels with B < ``low_modulation``), "low_B_rate" (their fraction wrong)}."""
    import cv2

    wrong, lab, valid = (np.asarray(x, bool) for x in (wrong, labelled, valid))
    wrong = wrong & lab
    B = np.asarray(modulation, np.float64)
    n, cc = cv2.connectedComponents(wrong.astype(np.uint8), connectivity=8)
    sizes = np.bincount(cc[wrong]) if wrong.any() else np.zeros(1, int)
    near = _within(~valid, radius)
    low = lab & (B < low_modulation)
    return {"wrong": int(wrong.sum()), "labelled": int(lab.sum()), "components": int(n - 1),
            "largest": int(sizes.max()), "near_invalid": int((wrong & near).sum()),
            "labelled_near_invalid": float((lab & near).sum() / max(lab.sum(), 1)),
            "median_B_wrong": float(np.median(B[wrong])) if wrong.any() else float("nan"),
            "median_B_labelled": float(np.median(B[lab])) if lab.any() else float("nan"),
            "low_B_labelled": int(low.sum()), "low_B_rate": float((low & wrong).sum() / max(low.sum(), 1))}


def reference_suspects(phase_high, order_traditional, order_reference, ok, *, window: int = 5) -> dict:
    """Classify each wrong pixel (``order_reference >= 0``, ``ok``, traditional != reference) by the
    order its neighbours predict: the least-squares plane ``a + b dx + c dy`` through the absolute
    top phase ``phase_high + 2 pi k`` of the ``window`` x ``window`` neighbours that are ``ok`` and
    not wrong themselves (``k`` the reference order where there is one, the traditional elsewhere),
    evaluated at the pixel, gives ``k_plane = round((a - phase_high) / 2 pi)``.

    ``"reference"``: ``k_plane`` is the traditional order (the reference is the odd one out: an
    error of the reference, or of the reference's pixel); ``"traditional"``: it is the reference
    order (a genuine decode error); ``"neither"``, ``"undecided"`` (fewer than 3 neighbours, or
    collinear). Only an *isolated* reference error shows: a wrong patch of the reference carries
    its own neighbours' plane.

    ARGUMENTS: ``phase_high`` (H, W) rad; orders (H, W) int (-1: none); ``ok`` (H, W) bool.
    RETURNED VALUE: {"wrong", "reference", "traditional", "neither", "undecided", "margin_median"
    (median |plane order - k_plane| over the decided pixels, in orders: 0 is a clean decision,
    0.5 a coin toss), "reference_mask" (H, W) bool}."""
    ph = np.asarray(phase_high, np.float64)
    kt, kr = np.asarray(order_traditional, np.int64), np.asarray(order_reference, np.int64)
    ok = np.asarray(ok, bool)
    wrong = ok & (kr >= 0) & (kt >= 0) & (kt != kr)
    support = ok & ~wrong & ((kr >= 0) | (kt >= 0))
    Phi = ph + TWO_PI * np.where(kr >= 0, kr, kt)
    h = int(window) // 2
    H, W = ph.shape
    counts = {"reference": 0, "traditional": 0, "neither": 0, "undecided": 0}
    margins, ref_mask = [], np.zeros((H, W), bool)
    for y, x in zip(*np.nonzero(wrong)):
        y0, y1, x0, x1 = max(y - h, 0), min(y + h + 1, H), max(x - h, 0), min(x + h + 1, W)
        s = support[y0:y1, x0:x1]
        yy, xx = np.nonzero(s)
        if yy.size < 3:
            counts["undecided"] += 1
            continue
        M = np.stack([np.ones(yy.size), xx + x0 - x, yy + y0 - y], axis=1).astype(np.float64)
        if np.linalg.matrix_rank(M) < 3:
            counts["undecided"] += 1
            continue
        a = np.linalg.lstsq(M, Phi[y0:y1, x0:x1][s], rcond=None)[0][0]
        q = (a - ph[y, x]) / TWO_PI
        k = int(np.rint(q))
        margins.append(abs(q - k))
        cls = "reference" if k == kt[y, x] else "traditional" if k == kr[y, x] else "neither"
        counts[cls] += 1
        ref_mask[y, x] = cls == "reference"
    return {"wrong": int(wrong.sum()), **counts,
            "margin_median": float(np.median(margins)) if margins else float("nan"), "reference_mask": ref_mask}


def gamma_bias(u, gamma: float, shifts):
    """The N-step phase error (rad, same shape as ``u``) of a fringe whose projected intensity is
    ``((1 + cos(u - delta_n)) / 2) ** gamma`` (a power-law projector response), decoded by
    least squares (``unwrap.phase_shift.wrapped_phase``) with the ``shifts`` delta_n (N,) rad.
    ``gamma`` 1: zero."""
    from unwrap.phase_shift import wrapped_phase

    u = np.asarray(u, np.float64)
    d = np.asarray(shifts, np.float64).reshape(-1, *([1] * u.ndim))
    I = ((1.0 + np.cos(u[None] - d)) / 2.0) ** float(gamma)
    ph = np.asarray(wrapped_phase(I, np.asarray(shifts, np.float64)).phase)
    return np.angle(np.exp(1j * (ph - u)))


def fit_gamma(deviation, u, shifts, gammas=None) -> dict:
    """The response ``gamma`` (grid ``gammas``, default 0.50-2.50 by 0.01) minimising the RMS of
    ``deviation - c - gamma_bias(u, gamma)`` (rad; ``c`` a constant offset of the two patterns,
    fitted per gamma), ``deviation`` and ``u`` (n,) rad.

    RETURNED VALUE: {"gamma", "rms" at it, "rms_gamma_1", "offset" c at it, "amplitude" (max
    |gamma_bias| over a period at the fitted gamma), "pixels", "at_edge" (the best is a grid end)}."""
    dev, u = np.asarray(deviation, np.float64).reshape(-1), np.asarray(u, np.float64).reshape(-1)
    if dev.size < 100:
        raise ExperimentError(f"fit_gamma: {dev.size} pixels, fewer than 100")
    grid = np.round(np.arange(0.5, 2.5001, 0.01), 2) if gammas is None else np.asarray(gammas, np.float64)
    rms = []
    for g in grid:
        e = dev - gamma_bias(u, g, shifts)
        rms.append(float(np.sqrt(np.mean((e - e.mean()) ** 2))))
    i = int(np.argmin(rms))
    e = dev - gamma_bias(u, grid[i], shifts)
    one = dev - gamma_bias(u, 1.0, shifts)
    period = np.linspace(0.0, TWO_PI, 360, endpoint=False)
    return {"gamma": float(grid[i]), "rms": rms[i], "rms_gamma_1": float(np.sqrt(np.mean((one - one.mean()) ** 2))),
            "offset": float(e.mean()), "amplitude": float(np.abs(gamma_bias(period, grid[i], shifts)).max()),
            "pixels": int(dev.size), "at_edge": i in (0, len(grid) - 1)}


def unit_deviation(measured, *, max_deviation: float = 0.3):
    """(deviation, u) (n,) rad of a capture: ``u = Phi_top / f_top`` the unit phase the top
    frequency's plane predicts (:func:`experiments.pixel_twin.unit_phase_bias`'s), ``deviation =
    wrap(phi_1 - u)`` of the stored unit phase, on the labelled pixels with ``|deviation| <
    max_deviation`` (an order-level outlier or a reference error is no response curve)."""
    import h5py

    from unwrap.dataset_schema import decode_phase

    with h5py.File(measured.real_file, "r") as h5:
        phi1 = decode_phase(h5[f"{measured.orientation}/phase"][0, 0])
    lab = measured.lab
    u = ((measured.Phi - measured.r) * (measured.freqs[0] / measured.freqs[-1]))[lab]
    d = np.angle(np.exp(1j * (phi1[lab] - u)))
    keep = np.isfinite(d) & (np.abs(d) < max_deviation)
    return d[keep], u[keep]


def error_coincidence(wrong_real, wrong_twin, labelled, *, radius: float = 5.0) -> dict:
    """How many of a twin's wrong pixels (H, W) bool lie within ``radius`` px of a real wrong pixel,
    against the share of the ``labelled`` pixels that do (what a twin whose errors fall anywhere
    would score). RETURNED VALUE: {"twin_wrong", "near", "fraction", "chance"}."""
    wr, wt, lab = (np.asarray(x, bool) for x in (wrong_real, wrong_twin, labelled))
    near = _within(wr, radius)
    return {"twin_wrong": int(wt.sum()), "near": int((wt & near).sum()),
            "fraction": float((wt & near).sum() / max(wt.sum(), 1)),
            "chance": float((lab & near).sum() / max(lab.sum(), 1))}


def _interior(ok):
    """(H, W) bool: ``ok`` pixels whose whole 5x5 box is ``ok`` (capture_sensor's pixels)."""
    import cv2

    return ok & (cv2.boxFilter(ok.astype(np.float64), -1, (5, 5), normalize=True,
                               borderType=cv2.BORDER_CONSTANT) > 0.999)


def noise_match(real, twin, *, full_well_e: float, read_noise_e: float, bits: int = 8, bins: int = 10) -> dict:
    """The pixel twin's noise against the capture's and against its own sensor.

    ``real``: :func:`experiments.pixel_twin.measure_capture` of the capture (with frames: A, B of
    the top frequency); ``twin``: the same of a pixel twin written from it (no frames needed) with
    the sensor ``full_well_e`` / ``read_noise_e``.

    1. ``capture``/``twin``: ``sigma_I`` per decile of ``A`` (:func:`experiments.pixel_twin.sensor_fit`)
       from each file's own plane residuals, on the pixels interior to both; ``worst``: the largest
       ``|twin / capture - 1|`` over the deciles.
    2. ``true``: per decile of ``B``, the robust spread (1.4826 MAD) of the twin's true phase error
       ``wrap(phi_twin - Phi_top)`` (it is rendered from ``Phi_top``, the capture's plane) on its
       labelled pixels, and the sensor's ``sqrt(2 / N) sigma_I / B`` with ``sigma_I^2 = A / fw +
       (read / fw)^2 + 1 / (12 (2^bits - 1)^2)`` (median over the decile); ``true_worst`` the
       largest ``|measured / predicted - 1|``; ``estimated``: what the plane residual estimator
       (``unwrap.reliability.plane_residual_noise`` on the twin's residuals, interior pixels of the
       decile) reads for the same noise, ``estimator_worst`` its largest ``|estimated / measured - 1|``
       (an estimator reading k times high fits a sensor k times noisier than the capture's, and the
       twin then reads k times the capture: the ``worst`` of 1.).
    3. ``pixel_sd``: the unit phase's robust spread about its 15x15 local bias
       (:func:`experiments.pixel_twin.unit_phase_bias`), capture and twin."""
    import h5py

    from unwrap.dataset_schema import decode_phase
    from unwrap.reliability import plane_residual_noise

    from .pixel_twin import sensor_fit, unit_phase_bias

    top = real.sets[-1]
    N = len(top["shifts"])
    both = _interior(real.ok) & _interior(twin.ok)
    fits = {name: sensor_fit(m.r[both], top["A"][both], top["B"][both], N, bins=bins, bits=bits)
            for name, m in (("capture", real), ("twin", twin))}
    ratio = np.asarray(fits["twin"]["sigma_I"]) / np.asarray(fits["capture"]["sigma_I"])
    with h5py.File(twin.real_file, "r") as h5:
        ph = decode_phase(h5[f"{twin.orientation}/phase"][0, len(twin.freqs) - 1])
    lab = twin.lab & np.isfinite(ph) & real.ok
    err = np.angle(np.exp(1j * (ph - (real.Phi - real.r))))[lab]
    A, B, inner, resid = top["A"][lab], top["B"][lab], _interior(twin.ok)[lab], twin.r[lab]
    q2 = 1.0 / (12.0 * ((1 << bits) - 1) ** 2)
    pred = math.sqrt(2.0 / N) * np.sqrt(np.maximum(A, 0.0) / full_well_e + (read_noise_e / full_well_e) ** 2 + q2) / B
    edges = np.quantile(B, np.linspace(0.0, 1.0, bins + 1))
    rows = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        s = (B >= lo) & (B <= hi)
        if s.sum() >= 100 and (s & inner).sum() >= 100:
            rows.append({"B": float(np.median(B[s])), "measured": float(1.4826 * np.median(np.abs(err[s]))),
                         "predicted": float(np.median(pred[s])), "pixels": int(s.sum()),
                         "estimated": plane_residual_noise(resid[s & inner], B[s & inner], N)["sigma_phase_rad"]})
    sd = {name: unit_phase_bias(m.real_file, m.orientation, window=15, measured=m)["pixel_sd"]
          for name, m in (("capture", real), ("twin", twin))}
    return {"A": fits["capture"]["A"], "capture": fits["capture"]["sigma_I"], "twin": fits["twin"]["sigma_I"],
            "worst": float(np.max(np.abs(ratio - 1.0))), "true": rows,
            "true_worst": float(max(abs(r["measured"] / r["predicted"] - 1.0) for r in rows)) if rows else float("nan"),
            "estimator_worst": float(max(abs(r["estimated"] / r["measured"] - 1.0) for r in rows)) if rows else float("nan"),
            "pixel_sd": sd}


def decoded(path, orientation: str = "v", sample: int = 0) -> dict:
    """One sample of a capture export or pixel twin as the MF decode from its lowest to its top
    frequency sees it (``unwrap.dataset``): numpy (H, W) "phase_high" rad, "modulation_high",
    "order_traditional", "order_reference" (-1: none), "valid", "labelled", "wrong"."""
    import h5py

    from unwrap.dataset import FringeOrderDataset
    from unwrap.dataset_schema import read_attrs

    with h5py.File(path, "r") as h5:
        freqs = sorted(float(f) for f in read_attrs(h5)["frequencies"])
    it = FringeOrderDataset(path, method="mf", frequencies=(freqs[0], freqs[-1]), orientation=orientation,
                            crop=None, seed=0)[sample]
    kt, kr = it["order_traditional"].numpy().astype(np.int64), it["order_true"].numpy().astype(np.int64)
    valid = it["valid"].numpy().astype(bool)
    lab = kr >= 0
    return {"phase_high": it["phase_high"][0].double().numpy(), "modulation_high": it["modulation_high"][0].double().numpy(),
            "order_traditional": kt, "order_reference": kr, "valid": valid, "labelled": lab, "wrong": lab & (kt != kr)}


def contrast(measured) -> dict:
    """The top frequency's contrast ``B / A`` on the capture's interior valid pixels (those of
    :func:`experiments.pixel_twin.capture_sensor`): {"median", "p10"}."""
    top = measured.sets[-1]
    m = _interior(measured.ok)
    c = top["B"][m] / np.maximum(top["A"][m], 1e-9)
    return {"median": float(np.median(c)), "p10": float(np.quantile(c, 0.1))}


def moved_orders(measured, decode: dict) -> dict:
    """Pixels whose order the outlier pass of :func:`experiments.pixel_twin._absolute_top` moved (the
    2 pi spikes the pixel twin's geometry had before commit f601c0e): ``|Phi moved - Phi| > pi``
    with ``Phi = phase_high + 2 pi k`` (``k`` the reference order where there is one, the
    traditional elsewhere), on the decoded (``ok``) pixels; ``decode``: :func:`decoded` of the same
    file. RETURNED VALUE: {"decoded", "moved", "moved_labelled"}."""
    k = np.where(decode["labelled"], decode["order_reference"], decode["order_traditional"])
    Phi = decode["phase_high"] + TWO_PI * k
    moved = measured.ok & (np.abs(measured.Phi - Phi) > math.pi)
    return {"decoded": int(measured.ok.sum()), "moved": int(moved.sum()), "moved_labelled": int((moved & measured.lab).sum())}
