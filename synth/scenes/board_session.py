"""A complete calibration session of the paper, rendered from the twin (supplementary section 2):
the 9x11 circle board (20 mm pitch, 5 / 2 mm circles) at 9 poses tilted within +-10 deg about x
and +-20 deg about y, horizontal and vertical fringes with 12 steps at frequencies 1, 8 and 48,
plus a white frame, written in the capture layout of DESIGN.md with ``truth.json`` beside it.
``pattern="graycode"`` renders a Gray-code calibration session instead (OpenCV's GrayCodePattern:
column and row bits with their inverses, a white and a black frame; ``capture.toml`` with
``[pattern] kind = "graycode"``, the layout of :mod:`unwrap.graycode_capture`), as labs that
calibrate with Moreno & Taubin's method capture it.

The world frame is the board at its reference (untilted) pose, so pose 0 has ``R = R_cam``,
``t = t_cam`` and the board centre stays at the world origin for every pose. A system whose world
is elsewhere (an OpenCV rig's world is its camera) gets the board placed in its view instead
(:func:`board_reference_pose`); a session whose board either device barely sees is refused.
"""
from __future__ import annotations

import json
import logging
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import tomli_w

from unwrap.safe_output import write_text

from .boards import BoardTexture
from ..effects.spec import Effects, Noise
from ..errors import SynthError
from .objects import Board
from ..renderer.output import write_pngs, write_truth_h5
from .poses import rotation_xyz_deg
from ..renderer.render import render
from .scene import Scene
from .sequence import PatternSpec, check_fringe_periods, gray_sequence, phase_sequence

#: (rx, ry) tilts in degrees: the 3 x 3 grid of the paper's (0 +- 10, 0 +- 20, 0).
log = logging.getLogger(__name__)

PAPER_TILTS_DEG = [(0, 0), (10, 0), (-10, 0), (0, 20), (0, -20), (10, 20), (10, -20), (-10, 20), (-10, -20)]


def session_tilts(n_poses: int, seed: int = 0) -> list:
    """``n_poses`` (rx, ry) tilts: the paper's 9 first, then random ones within +-10 / +-20 deg."""
    if n_poses < 1:
        raise SynthError(f"poses: expected >= 1, got {n_poses}")
    tilts = list(PAPER_TILTS_DEG[:n_poses])
    rng = np.random.default_rng(seed)
    while len(tilts) < n_poses:
        tilts.append((float(rng.uniform(-10, 10)), float(rng.uniform(-20, 20))))
    return tilts


def capture_toml(board, steps, frequencies, camera_size, projector_size, extra=None, pattern=None,
                 source: str = "calib render-board") -> str:
    """The text of capture.toml (DESIGN.md) for ``board`` (``calib.board.Board``, or None for a
    capture without a board) and the pattern (``pattern``: the ``[pattern]`` table instead of
    steps and frequencies, e.g. a Gray-code one); ``source``: the command named in its header."""
    tables = {"board": board.to_dict()} if board is not None else {}
    tables.update({"pattern": pattern or {"steps": list(steps), "frequencies": list(frequencies)},
                   "camera": {"size": list(camera_size)}, "projector": {"size": list(projector_size)}})
    if extra:
        tables["render"] = extra
    return f"# Rendered by sltwin synth ({source}); layout of DESIGN.md\n\n" + tomli_w.dumps(tables)


def _gray_pattern_table(scene) -> dict | None:
    """The ``[pattern]`` table of a scene that renders a Gray-code-only session in the layout of
    :mod:`unwrap.graycode_capture` (every bit of one block size, with inverses for all or none,
    white and black where there are no inverses, no fringes), else None."""
    gray = [p for p in scene.patterns if p.kind == "gray"]
    if not gray or any(p.kind == "fringe" for p in scene.patterns) or len({p.block for p in gray}) != 1:
        return None
    block, inverse = gray[0].block, any(p.inverse for p in gray)
    expected = {p.name for o in {p.orientation for p in gray}
                for p in gray_sequence(o, scene.system.projector.size, inverse=inverse, block=block)}
    names = {p.name for p in scene.patterns}
    if {p.name for p in gray} != expected or (not inverse and not {"white", "black"} <= names):
        return None
    return {"kind": "graycode", "block_px": int(block), "inverse": inverse}


def scene_capture_toml(scene) -> str | None:
    """capture.toml text (DESIGN.md) describing the frames a scene renders, so that ``calib unwrap``
    reads ``calib render``'s output as it is: the phase-shift ladder, or a Gray-code-only session
    (:func:`_gray_pattern_table`); None when the frames form neither (orientations with different
    frequencies or steps, non-integer frequencies, which the frame names cannot hold, partial or
    mixed Gray code)."""
    extra = {"scene": scene.name, "software": "sltwin synth"}
    sizes = (scene.system.camera.size, scene.system.projector.size)
    gray = _gray_pattern_table(scene)
    if gray is not None:
        return capture_toml(None, [], [], *sizes, extra, pattern=gray, source="calib render")
    ladders = {}
    for p in scene.patterns:
        if p.kind == "fringe" and p.step == 0:
            ladders.setdefault(p.orientation, []).append((p.frequency, p.steps))
    if not ladders or len({tuple(v) for v in ladders.values()}) != 1:
        return None
    ladder = next(iter(ladders.values()))
    if any(not float(f).is_integer() for f, _ in ladder):
        return None
    return capture_toml(None, [n for _, n in ladder], [int(f) for f, _ in ladder], *sizes, extra,
                        source="calib render")


def pose_jitter(n_poses: int, rotation_deg: float, translation_mm: float, seed: int) -> list:
    """``n_poses`` random rigid perturbations ``(R (3,3), t (3,) mm)`` of the board -> world pose:
    rotation about a uniformly random axis by an angle uniform in [0, ``rotation_deg``] degrees,
    translation uniform in the cube [-``translation_mm``, ``translation_mm``]^3. Models placing
    the board again by hand for a repeated session (the detector's pixel-phase dependent centre
    errors are then drawn anew, as in a real re-capture)."""
    if not (rotation_deg >= 0 and translation_mm >= 0) or not np.isfinite(rotation_deg + translation_mm):
        raise SynthError(f"pose jitter: expected finite values >= 0, got {rotation_deg!r} deg, {translation_mm!r} mm")
    from calib.rotation import matrix_from_rotvec

    rng = np.random.default_rng([int(seed), 7919])
    out = []
    for _ in range(n_poses):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = np.radians(rng.uniform(0.0, rotation_deg))
        out.append((matrix_from_rotvec(axis * angle), rng.uniform(-translation_mm, translation_mm, 3)))
    return out


#: Fewer than this fraction of the board's points in view of the camera or the projector in a
#: pose, and the session is refused (nothing to calibrate from).
MIN_POINTS_IN_VIEW = 0.25


def _in_view(device, points_world) -> int:
    q = device.project(points_world)
    W, H = device.size
    return int(np.sum((q[:, 0] >= 0) & (q[:, 0] <= W - 1) & (q[:, 1] >= 0) & (q[:, 1] <= H - 1)))


def board_reference_pose(system, board) -> tuple[np.ndarray, np.ndarray]:
    """Where the session's untilted board sits: ``(R_world_board, t_world_board)``.

    The world origin with the identity rotation when the board placed there faces the camera and
    the camera and the projector both see most of it (the built-in system, whose world is the
    paper's board at pose 1). Otherwise (a system whose world is, e.g., the camera frame) the
    board faces the camera (its z axis towards it, x right, y up in the image), centred where
    the camera's and the projector's optical axes pass closest, moved back along the camera's
    axis until it spans at most 60 % of the image."""
    pts = board.points_board()
    if (_in_view(system.camera, pts) >= 0.75 * len(pts) and _in_view(system.projector, pts) >= 0.75 * len(pts)
            and (system.camera.R @ np.array([0.0, 0.0, 1.0]))[2] < 0):
        return np.eye(3), np.zeros(3)
    cam, prj = system.camera, system.projector
    c_cam, c_prj = cam.center_world, prj.center_world
    a_cam, a_prj = cam.R[2], prj.R[2]                 # optical axes (device z) in world
    b = a_cam @ a_prj
    w = c_cam - c_prj
    denom = 1.0 - b * b
    depth = (b * (a_prj @ w) - (a_cam @ w)) / denom if denom > 1e-9 else 0.0
    extent = np.ptp(pts[:, :2], axis=0).max()
    fit = extent * max(cam.fx / cam.width, cam.fy / cam.height) / 0.6   # board spans 60 % of the image
    depth = max(depth, fit)
    R_world_board = cam.R.T @ np.diag([1.0, -1.0, -1.0])
    return R_world_board, c_cam + depth * a_cam


def session_patterns(system, pattern: str, steps, frequencies, gray_block_px: int = 1) -> tuple[list, dict | None]:
    """(PatternSpecs, the ``[pattern]`` table or None) of a session: ``"phase-shift"`` (a white
    frame + fringes) or ``"graycode"`` (white, black, column and row Gray code with inverses)."""
    if pattern == "graycode":
        specs = [PatternSpec("white", "white"), PatternSpec("black", "black")]
        for o in ("v", "h"):
            specs += gray_sequence(o, system.projector.size, inverse=True, block=int(gray_block_px))
        return specs, {"kind": "graycode", "block_px": int(gray_block_px), "inverse": True}
    if pattern != "phase-shift":
        raise SynthError(f"pattern: expected 'phase-shift' or 'graycode', got {pattern!r}")
    specs = [PatternSpec("white", "white")] + phase_sequence(("v", "h"), frequencies, int(steps))
    check_fringe_periods(specs, system.projector.size)
    return specs, None


def render_board_session(out_dir, system=None, *, steps: int = 12, frequencies=(1, 8, 48), n_poses: int = 9,
                         bits: int = 8, seed: int = 0, noise: Noise | None = Noise(), board=None,
                         effects: Effects | None = None, truth_h5: bool = False, jitter=None,
                         pattern: str = "phase-shift", gray_block_px: int = 1, progress=None) -> dict:
    """Render the session into ``out_dir`` (capture.toml, pose_XX/*.png, truth.json); returns
    the truth dictionary. ``board``: a :class:`synth.scenes.boards.BoardTexture` or a ``calib.board.Board``
    (default: the paper's board). ``noise`` None renders noise-free; its seed is offset per pose.
    ``pattern``: ``"phase-shift"`` (steps, frequencies) or ``"graycode"`` (Gray code in blocks of
    ``gray_block_px`` projector pixels; :func:`session_patterns`).
    ``jitter`` ``(rotation_deg, translation_mm)`` perturbs every board pose at random
    (``pose_jitter``, drawn from ``seed``): a repeated session with the board placed again.
    One progress line per pose goes to the ``synth`` logger (or to ``progress``, a callable)."""
    from calib.io.calibration_json import system_to_dict
    from calib.system import default_system

    system = system or default_system()
    freqs = [int(f) if float(f).is_integer() else float(f) for f in frequencies]
    patterns, pattern_table = session_patterns(system, pattern, steps, freqs, gray_block_px)
    base = effects or Effects()
    base = replace(base, bits=int(bits))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    poses, visible, timings = [], [], []
    Rc, tc = system.camera.R, system.camera.t
    texture = board if isinstance(board, BoardTexture) else BoardTexture() if board is None else BoardTexture(board)
    pts = texture.board.points_board()
    perturb = pose_jitter(n_poses, *jitter, seed) if jitter is not None else None
    R0, t0_world = board_reference_pose(system, texture.board)
    if base.reference_distance_mm is None:   # exposed for the board, wherever it was placed
        base = replace(base, reference_distance_mm=float(np.linalg.norm(t0_world - system.projector.center_world)))
    placed = []
    for i, (rx, ry) in enumerate(session_tilts(n_poses, seed)):
        R_world_board = R0 @ rotation_xyz_deg([rx, ry, 0.0])
        t_world_board = t0_world.copy()
        if perturb is not None:
            R_world_board, t_world_board = perturb[i][0] @ R_world_board, t0_world + perturb[i][1]
        Xw = pts @ R_world_board.T + t_world_board
        seen = {d: _in_view(getattr(system, d), Xw) for d in ("camera", "projector")}
        if min(seen.values()) < MIN_POINTS_IN_VIEW * len(pts):
            raise SynthError(f"pose {i + 1} (tilt {rx:+.0f}, {ry:+.0f} deg): the camera sees {seen['camera']} and "
                             f"the projector {seen['projector']} of the board's {len(pts)} points: this system does "
                             "not view the board where the session places it")
        placed.append((R_world_board, t_world_board))
    for i, ((rx, ry), (R_world_board, t_world_board)) in enumerate(zip(session_tilts(n_poses, seed), placed)):
        t0 = time.perf_counter()
        eff = replace(base, noise=replace(noise, seed=int(noise.seed) + 1000 * int(seed) + i) if noise else None)
        scene = Scene(system, [Board("board", R_world_board, t_world_board, texture)], patterns, eff,
                      name=f"pose_{i:02d}")
        result = render(scene)
        pose_dir = out_dir / f"pose_{i:02d}"
        write_pngs(result, pose_dir)
        if truth_h5:
            write_truth_h5(result, scene, pose_dir / "truth.h5")
        R_cam_board = Rc @ R_world_board
        poses.append({"R": R_cam_board.tolist(), "t": (Rc @ t_world_board + tc).tolist(), "tilt_deg": [rx, ry, 0.0]})
        visible.append(_in_view(system.camera, pts @ R_world_board.T + t_world_board))
        timings.append(time.perf_counter() - t0)
        (progress or log.info)(f"pose {i + 1}/{n_poses}: tilt ({rx:+.1f}, {ry:+.1f}) deg, {len(patterns)} images, "
                                 f"{visible[-1]}/{len(pts)} board points in view, {timings[-1]:.1f} s")
    skewed = {d: dev.skew for d, dev in system.devices().items() if dev.skew != 0}
    if skewed:
        (progress or log.info)("the rendered system has skew (" + ", ".join(f"{d} {s:+.4g} px" for d, s in skewed.items())
                               + "): a calibration whose model contains the truth estimates it (calib run --skew)")
    write_text(out_dir / "capture.toml", capture_toml(
        texture.board, [int(steps)] * len(freqs), freqs, system.camera.size, system.projector.size,
        {"bits": int(bits), "seed": int(seed), "noise": noise is not None, "software": "sltwin synth"},
        pattern=pattern_table))
    truth = system_to_dict(system)
    truth.update({"board_poses": poses, "board": texture.board.to_dict(),
                  "board_points_in_view": visible,
                  "pattern": pattern_table or {"steps": int(steps), "frequencies": freqs},
                  "effects": base.to_dict(), "noise": None if noise is None else vars(noise) if hasattr(noise, "__dict__") else str(noise),
                  "seed": int(seed), "jitter": None if jitter is None else [float(j) for j in jitter],
                  "render_seconds": timings})
    write_text(out_dir / "truth.json", json.dumps(truth, indent=1, default=str) + "\n")
    return truth
