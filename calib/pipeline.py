"""Calibrate a capture folder, or point observations, and write every output: what ``calib run``
and ``calib demo`` do, one function each.

1. captures -> observations (:func:`calib.detect.captures.observations_from_captures`: unwrapping, board
   detection, projector pixels from a local phase fit);
2. observations -> calibration (:func:`calib.calibrate.run_calibration`: Zhang seeds, joint
   bundle adjustment; again with per-view noise levels where views stand out,
   :func:`calib.calibrate.reweight_views`);
3. where skew is held at 0, a refit with skew free (:mod:`calib.uncertainty.skew_check`), which warns when
   the data need a skew (a zero-skew model of a skewed system is biased);
4. the uncertainty it reports (:func:`calib.uncertainty.assess_uncertainty`: the per-pose error
   model's sigmas by default, optionally a jackknife or bootstrap over poses beside them, the
   residual diagnostics); the board warp is estimated by default where the views allow it
   (``board_warp="auto"``: 4 or more views);
5. the outputs in ``out``: ``calibration.json`` (DESIGN.md keys plus uncertainties, residuals,
   board poses, solver facts, the skew check and, for captures, the capture summary),
   ``camera.cameramodel``, ``projector.cameramodel``, ``residuals.png`` and, with
   ``figures="all"``, ``residuals_per_pose.png`` and ``residuals_on_board.png``
   (:mod:`calib.uncertainty.diagnostics`); for captures also
   ``observations.json`` and ``detections.png`` (:mod:`calib.io.capture_outputs`).

Progress goes to the ``calib`` logger. Errors are ``calib`` errors (``ValueError`` subclasses):
``ObservationError`` (too few views or points), ``InitError`` (degenerate views),
``BundleAdjustmentError``, ``CaptureError``, ``OutputError`` (outputs not writable).

SYNOPSIS

    from calib.pipeline import calibrate_captures
    run = calibrate_captures("out/demo/captures", "out/demo/twin_calibration")
    run.calibration.system.projector.fy, run.written["calibration.json"]
"""
from __future__ import annotations

import logging
import resource
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

from .adjustment.problem import BAConfig
from .calibrate import Calibration, reweight_views, run_calibration, with_view_noise
from .io.outputs import plot_residuals, write_outputs
from .errors import OutputError
from .observations import Observations
from .uncertainty.diagnostics import plot_residual_diagnostics
from .uncertainty.assess import assess_uncertainty, warp_allowed

if TYPE_CHECKING:    # the capture pipeline (unwrapping, detection: cv2, scipy) is imported where it is used
    from .detect.captures import CaptureObservations

log = logging.getLogger(__name__)


@dataclass
class CalibrationRun:
    """What :func:`calibrate_captures` / :func:`calibrate_observations` computed and wrote.

    - calibration: the :class:`calib.calibrate.Calibration` (system, adjustment, seeds, timings).
    - observations: the :class:`calib.observations.Observations` it was computed from.
    - captured: the per-pose facts of a capture folder (None for point observations).
    - written: ``{file name: path}``, or a note where a file could not be written (a
      ``.cameramodel`` of a device with skew).
    """

    calibration: Calibration
    observations: Observations
    captured: CaptureObservations | None
    written: dict
    stages_s: dict = field(default_factory=dict)
    peak_memory_mb: float = float("nan")


#: ``figures="auto"``: the per-pose figures are drawn up to this many views (above: the summary
#: figure ``residuals.png`` only; ``figures="all"`` draws them at any size).
FEW_VIEWS = 12
FIGURES = ("summary", "all", "auto", "none")
#: What ``calib run`` draws unless asked: the summary figure (~0.13 s at 9 views, drawn with Pillow;
#: the per-pose panels cost ~0.2 s more at 9 views, ~1.2 s at 100: docs/speed.md; ``figures="all"``
#: draws them).
DEFAULT_FIGURES = "summary"


def peak_memory_mb() -> float:
    """Peak resident memory of this process so far (MB; Linux ``ru_maxrss`` is in kB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def resolve_board_warp(config: BAConfig, obs: Observations, board_warp) -> BAConfig:
    """``config`` with the board warp decided: ``"auto"`` (estimated where the views allow it,
    :func:`calib.uncertainty.assess.warp_allowed`), True, False, or None (``config.board_warp`` as it is)."""
    if board_warp is None:
        return config
    if board_warp == "auto":
        on, why = warp_allowed(obs)
        log.info(f"board warp {'estimated' if on else 'not estimated'}: {why}")
        return replace(config, board_warp=on)
    return replace(config, board_warp=bool(board_warp))


def skew_check_outputs(obs: Observations, cal: Calibration, config: BAConfig) -> dict:
    """Refit with skew free (:mod:`calib.uncertainty.skew_check`) where ``config`` holds it at 0; a skew
    beyond the check's threshold is logged as a warning (shown even by ``calib run -q``).
    Returns ``{"skew_check": ...}`` for ``calibration.json``, or {} when nothing was checked."""
    from .uncertainty.skew_check import check_skew

    log.info("skew check: refitting with skew free")
    try:
        check = check_skew(obs, cal, config)
    except ValueError as exc:       # the refit's adjustment errors
        log.info(f"skew check: the refit failed ({exc}); not checked")
        return {}
    if check is None:
        return {}
    if check.significant():
        log.warning(f"warning: {check.message()}")
    else:
        log.info(check.message())
    return {"skew_check": check.to_dict()}


def _write_outputs(cal, fitted, out: Path, figures: str, per_pose: bool, captured, extra: dict,
                   skew_tol_px: float, stages: dict, lap) -> dict:
    """The figures, the capture outputs, then calibration.json and the camera models (last: the
    json's ``run`` block then holds every stage but its own, and the peak memory); ``lap(name)``
    records each stage's wall time in ``stages``. Returns {file name: path or note}."""
    try:
        figs = {}
        if figures != "none":
            out.mkdir(parents=True, exist_ok=True)
            figs["residuals.png"] = plot_residuals(cal, fitted, out / "residuals.png")
            lap("summary figure")
        if per_pose:
            figs.update(plot_residual_diagnostics(cal, fitted, cal.uncertainty.diagnostics, out))
            lap("per-pose figures")
        if captured is not None:
            from .io.capture_outputs import write_capture_outputs

            figs.update(write_capture_outputs(captured, out))
            lap("capture outputs")
        extra["run"] = {"stages_s": dict(stages), "peak_memory_mb": peak_memory_mb(), "figures": figures}
        written = write_outputs(cal, fitted, out, skew_tol_px=skew_tol_px, extra=extra, figures=False)
        lap("calibration.json + camera models")
    except OSError as exc:
        raise OutputError(f"cannot write outputs to {out}: {exc}") from None
    written.update(figs)
    return written


def calibrate_observations(obs: Observations, out, config: BAConfig | None = None, *,
                           skew_tol_px: float = 0.01, captured: CaptureObservations | None = None,
                           view_noise: bool = True, skew_check: bool = True, board_warp="auto",
                           resample: str = "none", draws: int = 30, figures: str = DEFAULT_FIGURES) -> CalibrationRun:
    """Calibrate from point observations and write the outputs into ``out`` (module docstring).

    A joint ``config`` with only one device observed falls back to single-device mode (logged).
    ``captured``: the capture folder's facts, written beside the calibration when given.
    ``view_noise``: give a view whose residuals stand out its own noise level and adjust again
    (:func:`calib.calibrate.reweight_views`; on the paper's real observations two views carry 3-4x
    the projector noise of the others, docs/calib.md); False: one noise level per device.
    ``skew_check``: where skew is held at 0, refit with it free and warn when the data need it
    (:func:`skew_check_outputs`; the result goes into ``calibration.json``).
    ``board_warp``: see :func:`resolve_board_warp`; ``resample``: "none", "jackknife" or
    "bootstrap" (``draws`` runs) beside the reported uncertainty (:mod:`calib.uncertainty.assess`).
    ``figures``: "summary" (default: ``residuals.png`` only), "all" (also the per-pose panels
    ``residuals_per_pose.png`` and ``residuals_on_board.png``, one panel per view: ~1.2 s at 100
    views), "auto" (all up to :data:`FEW_VIEWS` views, above the summary) or "none". The result carries the wall seconds per stage and the peak memory
    (also in ``calibration.json`` under ``run``).
    """
    if figures not in FIGURES:
        raise ValueError(f"figures: expected one of {FIGURES}, got {figures!r}")
    stages, t0 = {}, time.perf_counter()

    def lap(name):
        nonlocal t0
        now = time.perf_counter()
        stages[name] = stages.get(name, 0.0) + now - t0
        t0 = now
    config = resolve_board_warp(config or BAConfig(), obs, board_warp)
    devices = obs.devices()
    if config.mode == "joint" and len(devices) < 2:
        log.info(f"only {devices} observed: calibrating in single-device mode")
        config = replace(config, mode="single")
    log.info(f"{len(obs.views)} view(s) from {obs.source}; devices {devices}; mode {config.mode}")
    cal = reweight_views(obs, config) if view_noise else run_calibration(obs, config)
    lap("seeds + adjustment + reweighting")
    if not cal.ba.converged:
        rms = ", ".join(f"{d} {cal.ba.stats[d]['rms_px']:.3g} px" for d in ("camera", "projector")
                        if cal.ba.stats.get(d, {}).get("rms_px") is not None)
        log.warning(f"the adjustment did not converge in {cal.ba.iterations} iterations (residual RMS {rms}): the "
                    "estimate is not a minimum; observations that no camera + projector rig explains (e.g. one "
                    "orientation decoded with the wrong phase-shift sign) do this")
    fitted = with_view_noise(obs, cal.view_noise) if cal.view_noise else obs   # as the adjustment saw them
    extra = {} if captured is None else {"captures": captured.summary()}
    if skew_check:
        extra.update(skew_check_outputs(fitted, cal, config))
        lap("skew check")
    # The error model (and any resampling) is estimated on the final fit: after reweight_views,
    # with the observations weighted as that adjustment weighted them (the rebuilt Jacobian checks
    # itself against the adjustment's sigmas, so it must see the same point sigmas).
    cal.uncertainty = assess_uncertainty(cal, fitted, resample=resample, draws=draws)
    lap("uncertainty + residual diagnostics")
    per_pose = figures == "all" or (figures == "auto" and len(obs.views) <= FEW_VIEWS)
    if figures == "auto" and not per_pose:
        log.info(f"{len(obs.views)} views: the per-pose figures are not drawn (--figures all draws them)")
    written = _write_outputs(cal, fitted, Path(out), figures, per_pose, captured, extra, skew_tol_px, stages, lap)
    for name, path in written.items():
        if isinstance(path, str) and path.startswith("not written: "):
            log.warning(f"{name} not written: {path[len('not written: '):]}")
        else:
            log.info(f"wrote {name}: {path}")
    return CalibrationRun(cal, obs, captured, written, stages, peak_memory_mb())


def calibrate_captures(folder, out, config: BAConfig | None = None, *, capture_toml=None, method=None,
                       strict: bool = False, degree: int = 2, skew_tol_px: float = 0.01,
                       view_noise: bool = True, skew_check: bool = True, board_warp="auto",
                       resample: str = "none", draws: int = 30, figures: str = DEFAULT_FIGURES) -> CalibrationRun:
    """Calibrate from the board captures in ``folder`` and write the outputs into ``out``.

    ARGUMENTS
    - folder: capture folder (DESIGN.md layout, or a scanner's layout described by
      ``capture_toml``); see :mod:`calib.detect.captures`.
    - out: output folder (created).
    - config: :class:`calib.adjustment.problem.BAConfig` (default: joint, 5 distortion terms).
    - method: temporal unwrapping method (default: the capture's); strict: refuse the run when a
      pose cannot be used (default: skip it, and say so in the summary); degree: local polynomial
      degree of the projector-pixel fit (1 or 2).
    - skew_tol_px: see :func:`calib.io.mrcal_model.write_cameramodel`.
    - view_noise, skew_check, board_warp, resample, draws, figures: see :func:`calibrate_observations`.
    RETURNED VALUE: :class:`CalibrationRun`.
    """
    from .detect.captures import observations_from_captures

    captured = observations_from_captures(folder, capture_toml=capture_toml, method=method, strict=strict,
                                          degree=degree, keep_images=True)
    return calibrate_observations(captured.observations, Path(out), config, skew_tol_px=skew_tol_px,
                                  captured=captured, view_noise=view_noise, skew_check=skew_check,
                                  board_warp=board_warp, resample=resample, draws=draws, figures=figures)
