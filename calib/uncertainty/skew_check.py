"""Does a calibration with skew fixed at 0 fit its data? Refit with skew free and compare.

``calib run`` holds each device's skew ``K[0, 1]`` at 0 by default (mrcal's models have none).
When the true devices do have a skew, that model cannot fit the data: the misfit lands in the
other parameters, the principal points first (through the shared board poses and the camera error
transfer). Measured on ``calib render-board`` of the built-in system (camera skew -0.233 px,
projector -0.951 px), seed 0: with skew fixed the projector's residual given the camera's pixels
is 0.022 px against a phase-fit error of 0.0013 px, camera cy lies 3.5 sigma and projector cx 9.1
sigma from the truth; with skew estimated the residuals are at the measurement errors and every
intrinsic is within 0.9 sigma (docs/calib.md).

:func:`check_skew` refits the solved problem with every device's skew free, starting from the
solution (a few more iterations), and reports each skew with its sigma and how far the
principal point and focal lengths move, in sigmas of the zero-skew fit. ``significant()`` names
the devices whose skew is further than ``threshold_z`` sigmas from 0; then the zero-skew model
does not contain the data and its estimates are biased: calibrate with ``--skew``.

SYNOPSIS

    check = check_skew(obs, cal, config)     # cal = run_calibration(obs, config), skew fixed at 0
    check.significant(), check.message()

What the rendered built-in system gave (seed 0):

    >>> from calib.uncertainty.skew_check import SkewCheck
    >>> check = SkewCheck({"camera": -0.262, "projector": -0.962}, {"camera": 0.019, "projector": 0.012},
    ...                   {"camera.cy": -3.0}, {"camera": (0.072, 0.017)})
    >>> check.significant(), round(check.z("camera"), 1)
    (['camera', 'projector'], 13.8)
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace

from ..adjustment.solver import solve
from ..adjustment.problem import build_problem

#: |skew| / sigma beyond which the zero-skew model is reported as not fitting the data
DEFAULT_THRESHOLD_Z = 5.0
MOVED = ("fx", "fy", "cx", "cy")


@dataclass
class SkewCheck:
    """Result of :func:`check_skew`.

    - skew_px, sigma_px: {device: skew estimated in the refit, its 1-sigma}, px.
    - shift_sigma: {"camera.cy": (refit - zero-skew fit) / sigma of the zero-skew fit, ...} for
      fx fy cx cy of the checked devices.
    - rms_px: {device: (residual RMS with skew fixed, with skew free)}, px.
    - threshold_z: the significance threshold of ``significant``; seconds: time of the refit.
    """

    skew_px: dict
    sigma_px: dict
    shift_sigma: dict
    rms_px: dict
    threshold_z: float = DEFAULT_THRESHOLD_Z
    seconds: float = 0.0

    def z(self, device: str) -> float:
        return abs(self.skew_px[device]) / self.sigma_px[device] if self.sigma_px[device] > 0 else float("inf")

    def significant(self) -> list:
        """Devices whose skew differs from 0 by more than ``threshold_z`` sigmas."""
        return [d for d in self.skew_px if self.z(d) > self.threshold_z]

    def message(self) -> str:
        """One paragraph for the user (what the refit found and what to do)."""
        parts = [f"{d} skew {self.skew_px[d]:+.4g} +- {self.sigma_px[d]:.2g} px ({self.z(d):.1f} sigma)"
                 for d in self.skew_px]
        moved = sorted(self.shift_sigma.items(), key=lambda kv: -abs(kv[1]))[:3]
        text = "skew check (refit with skew free): " + ", ".join(parts)
        if self.significant():
            text += (f". The data favour a skew the zero-skew model lacks (residual RMS "
                     + ", ".join(f"{d} {a:.4f} -> {b:.4f} px" for d, (a, b) in self.rms_px.items())
                     + "; with skew free " + ", ".join(f"{k} moves {v:+.1f} sigma" for k, v in moved)
                     + "): the zero-skew estimates are biased by as much; calibrate with --skew.")
        else:
            text += f": consistent with 0 (within {self.threshold_z:g} sigma); the zero-skew model fits."
        return text

    def to_dict(self) -> dict:
        return {"skew_px": dict(self.skew_px), "sigma_px": dict(self.sigma_px),
                "z": {d: self.z(d) for d in self.skew_px}, "shift_sigma": dict(self.shift_sigma),
                "rms_px": {d: list(v) for d, v in self.rms_px.items()}, "threshold_z": self.threshold_z,
                "significant": self.significant(), "seconds": self.seconds}


def check_skew(obs, cal, config, *, threshold_z: float = DEFAULT_THRESHOLD_Z) -> SkewCheck | None:
    """Refit ``cal`` (a :class:`calib.calibrate.Calibration` of ``obs`` made with ``config``, a
    ``BAConfig``) with the skew of every device that held it at 0 set free; None when no device
    did (skew already estimated, fixed on purpose, or intrinsics fixed). Raises the adjustment's
    errors (ValueError subclasses) when the refit fails."""
    devices = [d for d in cal.ba.state.K
               if not config.device(d).estimate_skew
               and not ({"skew", "intrinsics"} & set(config.device(d).fixed))
               and "skew" not in dict(config.device(d).values)]
    if not devices:
        return None
    t0 = time.perf_counter()
    free = replace(config, progress=None,
                   **{d: replace(config.device(d), estimate_skew=True) for d in devices})
    res = solve(build_problem(obs, cal.ba.state.copy(), free))
    skew = {d: float(res.state.K[d][0, 1]) for d in devices}
    sigma = {d: float(res.std[f"{d}.skew"]) for d in devices}
    shift = {}
    for d in devices:
        for j, p in enumerate(MOVED):
            key = f"{d}.{p}"
            s0 = cal.ba.std.get(key)
            if s0:
                r, c = ((0, 0), (1, 1), (0, 2), (1, 2))[j]
                shift[key] = float((res.state.K[d][r, c] - cal.ba.state.K[d][r, c]) / s0)
    rms = {d: (float(cal.ba.stats[d]["rms_px"]), float(res.stats[d]["rms_px"]))
           for d in cal.ba.stats if d in ("camera", "projector") and cal.ba.stats[d].get("rms_px") is not None}
    return SkewCheck(skew, sigma, shift, rms, threshold_z, time.perf_counter() - t0)
