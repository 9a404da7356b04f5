"""The twin ball phase of the paper's Fig. 3, rendered by ``synth`` at the real ball's pose.

(The experiment behind the report's "twin (synth)" row; ``reports`` only lays out its result.)

The paper reconstructs one standard ball with real and twin calibrations and real and twin phase
(its Fig. 3). Its twin phase is a Blender render (dp-tpu ``standardball_phase_sim.mat``); here the
twin phase is rendered by our own renderer for the pose the real ball had:

1. reconstruct the real phase map with the real calibration (``calib.triangulate``,
   distortion-aware) and fit a sphere: centre (world = board pose 1, and camera frame), radius;
2. place a sphere of that radius at the same place relative to the twin's camera (the pose is
   carried through the camera frame, so a twin with its own world frame still sees the ball where
   the real camera saw it) and render the fringe stack in the twin: vertical fringes only (as the
   real file), ``steps`` = 12 per frequency, ``frequencies`` = 1, 8, 96 by default (the paper
   gives no fringe set for its ball; this is its calibration ladder 1, 8, 48 topped at the ball's
   f = 96; the 8 -> 96 ratio of 12 is unwrapped safely at the matched noise), 8-bit camera;
3. decode the stack with ``unwrap``'s in-memory decoder (:func:`unwrap.fused_mf.mf_unwrap_stacks`:
   N-step least squares, multi-frequency unwrapping) into the absolute phase of the top
   frequency, float64, NaN where invalid;
4. sensor noise matched to the real phase: the real map's phase noise is measured by
   :func:`unwrap.reliability.phase_noise_rad` (robust second differences, the smooth sphere's own curvature removed
   in quadrature with the same estimator on the noise-free truth), and the twin camera's full
   well (Poisson shot noise, 5 e- read noise, 8-bit quantisation) is solved so that the rendered
   phase carries the same noise, then checked by measuring the decoded render the same way;
5. footprint: the real file keeps only part of the ball's rim (its decoder's threshold is not
   published); by default the rendered mask keeps the decoded pixels of highest modulation, as many
   as the real map has valid pixels (``footprint="match-count"``), or all decoded pixels
   (``footprint="decoded"``). The overlap with the real footprint is reported (IoU).

The rendered phase is known exactly. Reconstructed with the true twin system (the one it was
rendered with), the sphere-fit RMS says what the twin phase itself contributes
(``info["floor"]``): ``render_and_decode`` decodes the unquantised float32 stack (rendering and
decoding alone, no camera sensor: ~1e-4 um), ``noise_free_8bit`` the 8-bit stack without sensor
noise (quantisation), ``rendered`` the returned phase (matched noise, footprint); each with the
paper's linear and our distortion-aware triangulation (the linear one is at the floor only for a
twin without distortion).

SYNOPSIS

    from calib import default_system
    from unwrap.phase_io import read_phase
    from experiments.twin_ball import render_twin_ball_phase
    real = default_system()
    phase, info = render_twin_ball_phase(real, real.ideal(), read_phase("standardball_phase_real.mat"), 96.0)
    info["pose"]["radius_mm"], info["floor"]["render_and_decode"]["distortion_aware_um"], info["footprint"]["iou"]
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from calib.triangulate import fit_sphere, points_from_phase, sphere_from_phase
from synth.effects.sensor import solve_full_well
from synth.effects.spec import Effects, Noise
from synth.errors import SynthError
from synth.renderer.geometry import compute_geometry
from synth.renderer.render import render
from synth.renderer.truth import phase_truth
from synth.scenes.objects import Sphere
from synth.scenes.scene import Scene
from synth.scenes.sequence import phase_sequence
from unwrap.fused_mf import mf_unwrap_stacks
from unwrap.phase_io import write_phase_file
from unwrap.reliability import phase_noise_rad

from .errors import ExperimentError

BALL_FREQUENCIES = (1.0, 8.0, 96.0)
"""Default fringe ladder of the twin ball (periods across the projector width)."""
BALL_STEPS = 12
"""Phase steps per frequency (the paper's N = 12)."""
READ_NOISE_E = 5.0
"""Read noise of the twin camera (electrons); the full well is solved to match the real noise."""

log = logging.getLogger(__name__)


def _say(progress, msg):
    """Progress to the ``synth`` logger: INFO when ``progress`` is asked for, else DEBUG."""
    log.log(logging.INFO if progress else logging.DEBUG, f"twin ball: {msg}")


def _check_phase_map(phase, system, what) -> np.ndarray:
    phase = np.asarray(phase, dtype=np.float64)
    if phase.ndim != 2:
        raise SynthError(f"{what}: expected a 2-D phase map, got shape {phase.shape}")
    if phase.shape != (system.camera.height, system.camera.width):
        raise SynthError(f"{what}: phase map {phase.shape[1]}x{phase.shape[0]} (W x H) does not match the "
                         f"camera image {system.camera.width}x{system.camera.height}")
    phase = phase.copy()
    phase[~np.isfinite(phase) | (phase == 0)] = np.nan
    return phase


def fit_ball_pose(system, phase, frequency: float, method: str = "distortion-aware") -> dict:
    """Reconstruct a vertical-fringe phase map of a ball and fit a sphere.

    ARGUMENTS: system (calib.SystemModel); phase (H, W) absolute phase at ``frequency`` periods
    across the projector width (NaN or 0 invalid); method "distortion-aware" or "linear".
    RETURNED VALUE: ``{centre_world_mm (3,), centre_cam_mm (3,), radius_mm, rms_um, points, method}``;
    world = the calibration's world frame (board pose 1), camera = its camera frame.
    """
    phase = _check_phase_map(phase, system, "real ball phase")
    valid = np.isfinite(phase)
    if valid.sum() < 100:
        raise SynthError(f"real ball phase: only {int(valid.sum())} valid pixels; no sphere to fit")
    points_world, _, ok = points_from_phase(system, phase, frequency, "v", method)
    if ok.sum() < 100:
        raise SynthError(f"real ball phase: only {int(ok.sum())} pixels triangulate; wrong calibration or frequency?")
    centre, radius, residuals = fit_sphere(points_world[ok])
    rms_um = float(1000 * np.sqrt(np.mean(residuals ** 2)))
    centre_cam = system.camera.R @ centre + system.camera.t
    if not (np.isfinite(radius) and radius > 0 and centre_cam[2] > radius):
        raise SynthError(f"real ball phase: the fitted sphere (centre {np.round(centre_cam, 2).tolist()} mm in the "
                         f"camera frame, radius {radius:.3g} mm) is not in front of the camera")
    if rms_um > 0.05 * 1000 * radius:
        raise SynthError(f"real ball phase: the sphere fit leaves {rms_um:.0f} um RMS on a {radius:.1f} mm radius; "
                         "the map does not look like a ball (wrong frequency or orientation?)")
    return {"centre_world_mm": centre.tolist(), "centre_cam_mm": centre_cam.tolist(), "radius_mm": float(radius),
            "rms_um": rms_um, "points": int(ok.sum()), "method": method}


def _stacks(images, n_frequencies: int, steps: int) -> list:
    """A rendered fringe stack (K, H, W) -> one (steps, H, W) numpy stack per frequency."""
    stack = images.numpy() if hasattr(images, "numpy") else np.asarray(images)
    return [stack[i * steps:(i + 1) * steps] for i in range(n_frequencies)]


def _decode(images, frequencies, steps, width):
    """8-bit fringe stack (K, H, W) -> (absolute phase of the top frequency, valid, modulation B),
    by unwrap's in-memory decoder with a 2 % modulation threshold."""
    r = mf_unwrap_stacks(_stacks(images, len(frequencies), steps), list(frequencies), width=width,
                         min_modulation=0.02 * 255)
    return np.asarray(r.result.phase, dtype=np.float64), np.asarray(r.result.valid), np.asarray(r.modulation)


def _decode_float(images, frequencies, steps, width, lit):
    """Unquantised float32 stack -> absolute phase (float64, NaN outside ``lit``): the floor of
    rendering and decoding without a camera sensor."""
    r = mf_unwrap_stacks(_stacks(images, len(frequencies), steps), list(frequencies), width=width)
    return np.where(np.asarray(r.result.valid) & lit, np.asarray(r.result.phase, dtype=np.float64), np.nan)


def _iou(a, b) -> float:
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 0.0


def _floor(system, phase, frequency):
    lin = sphere_from_phase(system, phase, frequency, "v", "linear")
    return {"linear_um": lin["rms_um"],
            "distortion_aware_um": sphere_from_phase(system, phase, frequency, "v", "distortion-aware")["rms_um"],
            "radius_mm": lin["radius_mm"], "points": lin["points"]}


def _check_inputs(real_system, twin_system, real_phase, frequency, frequencies, steps, footprint, noise, bits):
    """Refuse what cannot be rendered (a SynthError naming it); returns (real phase, ladder)."""
    for kind in ("camera", "projector"):
        a, b = getattr(real_system, kind), getattr(twin_system, kind)
        if a.size != b.size:
            raise SynthError(f"twin ball: {kind} image sizes differ: real {a.size} vs twin {b.size}; "
                             "the twin must have the real system's image sizes")
    real_phase = _check_phase_map(real_phase, real_system, "real ball phase")
    freqs = [float(f) for f in frequencies]
    if len(freqs) < 2 or np.any(np.diff(freqs) <= 0) or freqs[0] > 1.0:
        raise SynthError(f"twin ball: frequencies {freqs}: need an increasing ladder starting at 1 period")
    if abs(freqs[-1] - float(frequency)) > 1e-9:
        raise SynthError(f"twin ball: the ladder {freqs} must end at the real phase's frequency {frequency:g}")
    if not (isinstance(steps, int) and steps >= 3):
        raise SynthError(f"twin ball: steps must be an integer >= 3, got {steps!r}")
    if footprint not in ("match-count", "decoded"):
        raise SynthError(f"twin ball: footprint must be 'match-count' or 'decoded', got {footprint!r}")
    if not (noise is None or noise == "match" or (isinstance(noise, (int, float)) and noise > 0)):
        raise SynthError(f"twin ball: noise must be 'match', None or a phase noise > 0 rad, got {noise!r}")
    if bits not in (8,):
        raise SynthError(f"twin ball: only an 8-bit camera is decoded here, got bits={bits!r}")
    return real_phase, freqs


@dataclass
class _TwinBall:
    """The twin scene of stage 2 and its noise-free decode."""

    system: object
    sphere: Sphere
    patterns: list
    geometry: object
    truth: np.ndarray           # (H, W) true absolute phase of the top frequency, NaN unlit
    lit: np.ndarray             # (H, W) bool
    clean: object               # RenderResult of the noise-free 8-bit stack, with its linear values
    phase0: np.ndarray          # its decoded phase
    valid0: np.ndarray
    freqs: list
    steps: int
    bits: int

    @property
    def width(self) -> int:
        return self.system.projector.width


def _place_ball(real_system, twin_system, real_phase, frequency, radius_mm, progress):
    """Stage 1: the real ball's pose, carried to the twin through the camera frame."""
    _say(progress, "[1/5] reconstructing the real ball (distortion-aware) and fitting the sphere")
    pose = fit_ball_pose(real_system, real_phase, frequency)
    radius = float(radius_mm) if radius_mm is not None else pose["radius_mm"]
    if not radius > 0:
        raise SynthError(f"twin ball: radius_mm must be > 0, got {radius_mm!r}")
    cam = twin_system.camera
    centre_twin_world = cam.R.T @ (np.asarray(pose["centre_cam_mm"]) - cam.t)
    _say(progress, f"      centre {np.round(pose['centre_cam_mm'], 3).tolist()} mm (camera frame), "
                   f"radius {pose['radius_mm']:.3f} mm, fit RMS {pose['rms_um']:.2f} um")
    return pose, radius, centre_twin_world


def _render_clean(twin_system, centre_world, radius, freqs, steps, bits, progress) -> _TwinBall:
    """Stage 2: the twin geometry and the noise-free 8-bit stack, decoded."""
    _say(progress, f"[2/5] twin geometry and the noise-free stack (v fringes, f = {freqs}, {steps} steps)")
    patterns = phase_sequence(("v",), freqs, steps)
    sphere = Sphere("ball", np.eye(3), centre_world, 0.8, radius)
    scene = Scene(twin_system, [sphere], patterns, Effects(bits=bits), "twin ball")
    geometry = compute_geometry(scene)
    truth, _, lit = phase_truth(geometry, twin_system.projector.size, "v", freqs[-1])
    if lit.sum() < 100:
        raise SynthError(f"twin ball: only {int(lit.sum())} camera pixels of the twin see the lit ball")
    clean = render(scene, geometry=geometry, keep_linear=True)
    phase0, valid0, _ = _decode(clean.images, freqs, steps, twin_system.projector.width)
    return _TwinBall(twin_system, sphere, patterns, geometry, truth, lit, clean, phase0, valid0, freqs, steps, bits)


def _match_noise(ball: _TwinBall, real_phase, noise, seed, progress) -> dict:
    """Stage 3: the sensor noise that gives the twin phase the real phase's noise; the noisy
    stack decoded (``phase``, ``valid``, ``B``) and the noise facts."""
    _say(progress, "[3/5] matching the sensor noise to the real phase")
    freqs, steps, bits = ball.freqs, ball.steps, ball.bits
    sigma_real = phase_noise_rad(real_phase, np.where(np.isfinite(real_phase), ball.truth, np.nan))
    sigma_clean = phase_noise_rad(ball.phase0, ball.truth)
    lin = ball.clean.linear.numpy()[(len(freqs) - 1) * steps:]
    A_lin, B_lin = lin.mean(0), np.abs(np.fft.fft(lin, axis=0)[1]) * 2 / steps
    inner = ball.lit & (B_lin > 0.25 * B_lin[ball.lit].max())
    target = sigma_real if noise == "match" else (None if noise is None else float(noise))
    full_well, images, sigma_twin = None, ball.clean.images, sigma_clean
    note = "noise-free render (8-bit quantisation only)"
    decoded = None
    if target is not None:
        goal = target
        for _ in range(3):
            full_well = solve_full_well(A_lin[inner], B_lin[inner], goal, steps, bits, READ_NOISE_E)
            if full_well is None:
                note = (f"the target {target:.3g} rad is below the 8-bit quantisation floor {sigma_clean:.3g} rad: "
                        "rendered noise-free")
                break
            noisy = Scene(ball.system, [ball.sphere], ball.patterns,
                          Effects(bits=bits, noise=Noise(full_well, READ_NOISE_E, seed)), "twin ball")
            images = render(noisy, geometry=ball.geometry).images
            decoded = _decode(images, freqs, steps, ball.width)
            sigma_twin = phase_noise_rad(decoded[0], ball.truth)
            note = (f"Poisson shot noise, full well {full_well:.0f} e-, read noise {READ_NOISE_E:g} e-, "
                    f"{bits}-bit quantisation")
            if abs(sigma_twin / target - 1) < 0.05:
                break
            goal *= target / sigma_twin
    if full_well is None:
        decoded = _decode(images, freqs, steps, ball.width)
        sigma_twin = phase_noise_rad(decoded[0], ball.truth)
    phase_n, valid_n, B_n = decoded
    _say(progress, f"      real phase noise {sigma_real:.4g} rad, twin {sigma_twin:.4g} rad ({note})")
    return {"phase": phase_n, "valid": valid_n, "B": B_n,
            "facts": {"mode": noise if isinstance(noise, str) or noise is None else "target", "real_rad": sigma_real,
                      "target_rad": target, "twin_rad": sigma_twin, "quantisation_only_rad": sigma_clean,
                      "full_well_e": full_well, "read_noise_e": READ_NOISE_E if full_well else None, "model": note,
                      "seed": seed}}


def _footprint(ball: _TwinBall, real_phase, noisy: dict, footprint: str, progress) -> tuple[np.ndarray, dict]:
    """Stage 4: the rendered phase kept where the real map has a footprint; returns the phase and
    the footprint, decoding and real-vs-truth facts."""
    _say(progress, "[4/5] footprint")
    phase_n, valid_n, B_n = noisy["phase"], noisy["valid"], noisy["B"]
    real_valid = np.isfinite(real_phase)
    decoded = valid_n & np.isfinite(phase_n)
    mask = decoded
    if footprint == "match-count" and decoded.sum() > real_valid.sum():
        threshold = np.sort(B_n[decoded])[::-1][int(real_valid.sum()) - 1]
        mask = decoded & (B_n >= threshold)
    phase = np.where(mask, phase_n, np.nan)
    truth, lit = ball.truth, ball.lit
    # a fringe-order error moves the absolute phase by 2 pi; a decoded order that differs from the
    # truth's only because the wrapped phase crossed its +-pi cut leaves the phase right
    both = real_valid & lit
    d_real = real_phase[both] - truth[both]
    to_px = ball.width / (2 * np.pi * ball.freqs[-1])
    facts = {
        "footprint": {"mode": footprint, "real_pixels": int(real_valid.sum()), "lit_pixels": int(lit.sum()),
                      "decoded_pixels": int(decoded.sum()), "pixels": int(mask.sum()), "iou": _iou(mask, real_valid),
                      "iou_decoded": _iou(decoded, real_valid), "iou_lit": _iou(lit, real_valid)},
        "decoding": {"order_errors_noise_free_8bit": int(np.sum(ball.valid0 & (np.abs(ball.phase0 - truth) > np.pi))),
                     "order_errors": int(np.sum(decoded & (np.abs(phase_n - truth) > np.pi))),
                     "order_errors_in_footprint": int(np.sum(mask & (np.abs(phase_n - truth) > np.pi)))},
        "real_minus_twin_truth": {"mean_rad": float(d_real.mean()), "std_rad": float(d_real.std()),
                                  "mean_prj_px": float(d_real.mean() * to_px), "std_prj_px": float(d_real.std() * to_px),
                                  "pixels": int(both.sum())},
    }
    return phase, facts


def _floors(ball: _TwinBall, phase, progress) -> tuple[dict, dict]:
    """Stage 5: the rendered phases reconstructed with the system that rendered them."""
    _say(progress, "[5/5] floor: the rendered phase reconstructed with the true twin system")
    scene = Scene(ball.system, [ball.sphere], ball.patterns, Effects(bits=ball.bits), "twin ball")
    float_phase = _decode_float(render(scene, geometry=ball.geometry, quantised=False).images,
                                ball.freqs, ball.steps, ball.width, ball.lit)
    f = ball.freqs[-1]
    floor = {"render_and_decode": _floor(ball.system, float_phase, f),
             "noise_free_8bit": _floor(ball.system, np.where(ball.valid0, ball.phase0, np.nan), f),
             "rendered": _floor(ball.system, phase, f)}
    lit = ball.lit
    accuracy = {"float_vs_truth_rms_rad": float(np.sqrt(np.nanmean((float_phase - ball.truth)[lit] ** 2))),
                "noise_free_8bit_vs_truth_rms_rad": float(np.sqrt(np.nanmean((ball.phase0 - ball.truth)[ball.valid0] ** 2)))}
    return floor, accuracy


def render_twin_ball_phase(real_system, twin_system, real_phase, frequency: float = 96.0, *,
                           frequencies=BALL_FREQUENCIES, steps: int = BALL_STEPS, radius_mm: float | None = None,
                           noise: str | float | None = "match", footprint: str = "match-count", bits: int = 8,
                           seed: int = 0, progress: bool = True):
    """Render the twin ball phase at the real ball's fitted pose (module docstring).

    ARGUMENTS
    - real_system: the calibration that reconstructs ``real_phase`` (its pose fit).
    - twin_system: the system the twin renders with (the true twin: e.g. ``real_system.ideal()``,
      what Blender represents, or the demo's twin); same camera and projector sizes as the real one.
    - real_phase: (H, W) absolute phase of vertical fringes at ``frequency`` periods across the
      projector width, NaN or 0 where invalid (dp-tpu ``standardball_phase_real.mat``: f = 96).
    - frequencies: the rendered ladder, increasing, starting at 1, ending at ``frequency``;
      steps: phase steps per frequency.
    - radius_mm: ball radius to render (default: the fitted radius).
    - noise: "match" (real phase noise, see the module docstring), None (noise-free 8-bit), or a
      target phase noise in rad.
    - footprint: "match-count" or "decoded" (module docstring); bits: camera bit depth; seed: noise seed.
    - progress: stage lines at INFO on the ``synth`` logger (else DEBUG).
    RETURNED VALUE: (phase (H, W) float64 rad, NaN where invalid; info dict, JSON-ready: pose,
    noise, footprint, floor, timings). Raises SynthError (or a calib error of the pose fit).
    """
    t_start = time.perf_counter()
    real_phase, freqs = _check_inputs(real_system, twin_system, real_phase, frequency, frequencies, steps,
                                      footprint, noise, bits)
    timings, t = {}, time.perf_counter()
    pose, radius, centre_twin_world = _place_ball(real_system, twin_system, real_phase, frequency, radius_mm,
                                                  progress)
    timings["pose fit"], t = time.perf_counter() - t, time.perf_counter()
    ball = _render_clean(twin_system, centre_twin_world, radius, freqs, steps, bits, progress)
    timings["render + decode, noise-free"], t = time.perf_counter() - t, time.perf_counter()
    noisy = _match_noise(ball, real_phase, noise, seed, progress)
    timings["noise matching"], t = time.perf_counter() - t, time.perf_counter()
    phase, facts = _footprint(ball, real_phase, noisy, footprint, progress)
    timings["footprint"], t = time.perf_counter() - t, time.perf_counter()
    floor, accuracy = _floors(ball, phase, progress)
    timings["floor"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_start
    _say(progress, f"      floor (distortion-aware) {floor['render_and_decode']['distortion_aware_um']:.2g} um "
                   f"(render + decode), {floor['noise_free_8bit']['distortion_aware_um']:.3f} um (8-bit), "
                   f"{floor['rendered']['distortion_aware_um']:.3f} um (matched noise); done in {timings['total']:.1f} s")
    facts["decoding"].update(accuracy)
    info = {
        "pose": {**pose, "centre_twin_world_mm": centre_twin_world.tolist(), "rendered_radius_mm": radius},
        "patterns": {"orientation": "v", "frequencies": freqs, "steps": steps, "images": len(ball.patterns),
                     "bits": bits, "decoder": "unwrap.fused_mf.mf_unwrap_stacks"},
        "noise": noisy["facts"],
        **facts,
        "floor": floor,
        "timings_s": timings,
    }
    return phase, info


def write_twin_ball_phase(path, phase, info: dict):
    """The rendered phase in DESIGN.md's phase layout (:func:`unwrap.phase_io.write_phase_file`):
    group ``v`` with ``phase`` (float64, NaN invalid) and ``valid``, attribute ``frequency``; the
    render facts as the JSON file attribute ``twin_ball``. Returns the path."""
    import json

    facts = json.dumps({k: v for k, v in info.items() if k != "file"}, default=float)
    return write_phase_file(path, {"v": {"phase": phase}}, frequency=float(info["patterns"]["frequencies"][-1]),
                            attrs={"twin_ball": facts})


def twin_ball_for_report(real_paths, phases: dict, out_dir, *, frequency: float = 96.0, render: bool | None = None,
                         render_system=None, options: dict | None = None, progress: bool = True):
    """The twin ball the twin-equivalence report lays out, or None.

    ``render``: render the twin ball phase at the real ball's fitted pose; default (None): when
    ``phases`` (``{"real": path, "twin": path}``) holds a real phase without a twin phase.
    ``render_system``: the system that renders it (default: the real calibration ``real_paths``
    without skew and distortion, what the Blender twin represents; "real": with them);
    ``options``: keyword arguments of :func:`render_twin_ball_phase`. The phase is written to
    ``out_dir/twin_ball_phase.h5`` (``v/phase``, ``v/valid``).
    RETURNED VALUE: None or (phase (H, W) rad, info dict with ``"file"``)."""
    from pathlib import Path

    from calib.io.record import load_calibration_record
    from unwrap.phase_io import read_phase

    phases = dict(phases or {})
    if render is None:
        render = "real" in phases and "twin" not in phases
    if not render:
        return None
    if "real" not in phases:
        raise ExperimentError("the twin ball render needs the real ball phase (--phase-real): its pose is fitted from it")
    real = load_calibration_record(real_paths, "real").system
    system = real if render_system == "real" else render_system if render_system is not None else real.ideal()
    phase, info = render_twin_ball_phase(real, system, read_phase(phases["real"]), frequency, progress=progress,
                                         **(options or {}))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    info["file"] = str(write_twin_ball_phase(out / "twin_ball_phase.h5", phase, info))
    return phase, info
