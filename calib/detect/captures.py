"""Board captures on disk -> point observations for ``calib run`` (camera and projector pixels).

Per pose folder: absolute phase of both orientations with ``unwrap/``, the board detected on the
white frame (or, without one, on the phase-shift background A, then on the modulation B), and the
projector pixel of every detected feature from a local fit of the decoded projector coordinates
(:mod:`calib.detect.marker_phase`), with its standard error. The result is an
:class:`calib.observations.Observations` the bundle adjustment takes as it is.

Session description (``capture.toml``, DESIGN.md) — the keys read here besides ``[board]``,
``[pattern]``, ``[camera]`` and ``[projector]``:

    [capture]
    preset = "design"          # or a real scanner's layout known to unwrap/ ("slstudio", ...)
    method = "mf"              # temporal unwrapping method (default: the preset's)
    poses = ["calseq1", ...]   # pose folders, relative to the capture folder (default: pose_*;
                               # capture_* for procam-graycode)
    board_image = ["white", "background", "modulation"]   # where to look for the board, in order

Gray-code-only sessions (``[pattern] kind = "graycode"``, or the ``procam-graycode`` preset; see
:mod:`unwrap.graycode_capture`) decode to block centres: the projector-pixel fit weighs every
valid pixel equally and models the quantisation in each point's standard error
(``calib.detect.marker_phase``, ``quantisation_px``).

The ``capture.toml`` may live outside the capture folder (``capture_toml=`` / ``--capture-toml``)
for presets whose frame names it does not describe (a real scanner's folder that must stay
untouched); the DESIGN.md layout reads its ``capture.toml`` from the capture folder itself.

Failure policy: a pose that cannot be used (a missing or unreadable frame, frames the description
does not account for, no board found) is skipped and the reason is reported in
:attr:`CaptureObservations.skipped`; ``strict=True`` refuses instead. Fewer than
``min_poses`` usable poses is always refused.
"""
from __future__ import annotations

import logging
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from unwrap.capture import BOARD_IMAGE_SOURCES, Capture

from ..board import Board
from ..errors import CaptureError
from .marker_phase import fit_projector_points, window_radii
from ..observations import ObservationError, Observations, ViewObservations

log = logging.getLogger(__name__)


def _size(meta, key, toml):
    size = meta.get(key, {}).get("size")
    if size is None:
        return None
    try:
        w, h = (int(v) for v in size)
    except (TypeError, ValueError):
        raise CaptureError(f"{toml}: [{key}] size must be [width, height], got {size!r}") from None
    if w <= 0 or h <= 0:
        raise CaptureError(f"{toml}: [{key}] size must be positive, got {size!r}")
    return (w, h)


def read_session(folder, capture_toml=None) -> Capture:
    """Describe the capture session in ``folder`` from its ``capture.toml`` (or ``capture_toml``),
    read once: an ``unwrap.capture.Capture`` with its board, poses and sizes (no frames yet)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise CaptureError(f"capture folder not found: {folder}")
    toml = Path(capture_toml) if capture_toml else folder / "capture.toml"
    if not toml.exists():
        raise CaptureError(f"{toml}: no capture description (capture.toml, DESIGN.md); "
                           "give one with --capture-toml for a real scanner's folder")
    from unwrap.capture import read_toml
    from unwrap.errors import UnwrapError

    try:
        meta = read_toml(toml)
    except UnwrapError as exc:
        raise CaptureError(str(exc)) from None
    if "board" not in meta:
        raise CaptureError(f"{toml}: missing [board] table (kind, rows, cols, spacing_mm, ...)")
    board = Board.from_dict(meta["board"], source=f"{toml} [board]")
    cap = meta.get("capture", {})
    preset = cap.get("preset", "design")
    if preset == "design" and capture_toml and Path(capture_toml).resolve() != (folder / "capture.toml").resolve():
        if not (folder / "capture.toml").exists():
            raise CaptureError(f"{folder}: the DESIGN.md layout keeps its capture.toml in the capture folder")
    if preset == "design":
        from unwrap.capture import check_design_description

        if capture_toml and Path(capture_toml).resolve() != (folder / "capture.toml").resolve():
            raise CaptureError(f"{capture_toml}: the DESIGN.md layout reads its frames' description from "
                               f"{folder / 'capture.toml'}; --capture-toml is for other presets")
        try:
            check_design_description(toml, meta)      # refuse a bad [pattern] now, not once per pose
        except UnwrapError as exc:
            raise CaptureError(str(exc)) from None
    if "poses" in cap:
        names = [str(p) for p in cap["poses"]]
    else:
        pattern = r"capture_\d+" if preset == "procam-graycode" else r"pose_\d+"
        names = sorted((p.name for p in folder.iterdir() if p.is_dir() and re.fullmatch(pattern, p.name)),
                       key=lambda n: int(n.split("_")[-1]))
    if not names:
        raise CaptureError(f"{folder}: no pose folders (pose_00, pose_01, ... or [capture] poses; capture_0, ... "
                           "for procam-graycode)")
    missing = [n for n in names if not (folder / n).is_dir()]
    if missing:
        raise CaptureError(f"{folder}: pose folder(s) listed in {toml.name} not found: {missing}")
    sources = tuple(cap.get("board_image", BOARD_IMAGE_SOURCES))
    bad = [s for s in sources if s not in BOARD_IMAGE_SOURCES]
    if bad or not sources:
        raise CaptureError(f"{toml}: [capture] board_image: unknown source(s) {bad}; "
                           f"expected a list from {BOARD_IMAGE_SOURCES}")
    return Capture(folder, preset, camera_size=_size(meta, "camera", toml), projector_size=_size(meta, "projector", toml),
                   toml=toml, description=meta, method=cap.get("method"), poses=[(n, folder / n) for n in names],
                   board_image=sources, board=board)


@dataclass
class PoseObservation:
    """One pose: the detection, the projector fit and what was used.

    - ids (N,), points_board (N, 3) mm, q_cam (N, 2) px, q_prj (N, 2) px (NaN where the phase fit
      failed), sigma_prj (N,) px.
    - board_image: the source the board was found on; notes: what was dropped and why.
    - seconds: {"unwrap": s, "detect": s, "phase_fit": s}.
    """

    name: str
    ids: np.ndarray
    points_board: np.ndarray
    q_cam: np.ndarray
    q_prj: np.ndarray
    sigma_prj: np.ndarray
    board_image: str
    notes: list = field(default_factory=list)
    seconds: dict = field(default_factory=dict)
    image_size: tuple = (0, 0)
    image: np.ndarray | None = None     # float32 copy of the board image, for figures only
    dprj_dcam: np.ndarray | None = None  # (N, 2, 2) d q_prj / d q_cam from the phase fit

    def view(self) -> ViewObservations:
        return ViewObservations(self.points_board, {"camera": self.q_cam, "projector": self.q_prj},
                                {"projector": np.where(np.isfinite(self.sigma_prj), self.sigma_prj, 1.0)},
                                self.ids, self.name, self.dprj_dcam)


def _board_image(source, white_path, results):
    from unwrap.capture import read_image

    if source == "white":
        return None if white_path is None else read_image(white_path).astype(np.float64)
    o = "v" if "v" in results else next(iter(results))
    return np.asarray(results[o].background if source == "background" else results[o].modulation, np.float64)


def observe_pose(session: Capture, name: str, pose_dir: Path, *, method: str | None = None,
                 detector=None, degree: int = 2, keep_image: bool = False, progress=None) -> PoseObservation:
    """Unwrap, detect and fit one pose (see the module docstring). ``detector(image, board)``
    defaults to :func:`calib.detect.detect_board`. Raises CaptureError / UnwrapError /
    DetectionError naming the problem. Progress goes to the ``calib`` logger (or to ``progress``,
    a callable taking one line, when given)."""
    from unwrap.capture import load_capture
    from unwrap.patterns import projector_coordinate
    from unwrap.pipeline import unwrap_orientation

    if detector is None:
        from . import detect_board as detector
    say = progress or log.info
    t0 = time.perf_counter()
    if session.preset == "design":
        cap = load_capture(session.folder, "design", pose=name, description=session.description)
    else:
        cap = load_capture(pose_dir, session.preset, description=session.description)
    method = method or session.method or cap.default_method
    missing = [o for o in ("v", "h") if o not in cap.orientations]
    if missing:
        raise CaptureError(f"{pose_dir}: no frames for orientation(s) {missing}: the projector needs "
                           "fringes along both columns (v) and rows (h)")
    results = {o: unwrap_orientation(oc, method) for o, oc in cap.orientations.items()}
    t1 = time.perf_counter()
    white = cap.orientations["v"].white
    shape = results["v"].result.phase.shape
    if session.camera_size and (shape[1], shape[0]) != tuple(session.camera_size):
        raise CaptureError(f"{pose_dir}: frames are {shape[1]}x{shape[0]}, capture.toml [camera] size "
                           f"says {session.camera_size[0]}x{session.camera_size[1]}")
    det, used, failures = None, None, []
    for source in session.board_image:
        image = _board_image(source, white, results)
        if image is None:
            continue
        try:
            det = detector(image, session.board)
            used = source
            break
        except ValueError as exc:   # DetectionError and other refusals of the detector
            failures.append(f"{source}: {exc}")
    if det is None:
        raise CaptureError(f"{pose_dir}: board not found ({'; '.join(failures) or 'no board image'})")
    t2 = time.perf_counter()
    maps, weights = {}, {}
    for o in ("v", "h"):
        r = results[o]
        maps[o] = projector_coordinate(r.result.phase, r.result.frequency, r.width)
        # phase: inverse phase variance B^2; a quantised Gray map: every valid pixel alike
        weights[o] = np.where(r.result.valid, 1.0 if r.quantisation_px else r.modulation ** 2, 0.0)
    feature = det.feature_px if session.board.kind == "circles" else np.zeros(len(det.q))
    radius, inner = window_radii(det.q, feature)
    fit = fit_projector_points(det.q, maps["v"], maps["h"], weight_u=weights["v"], weight_v=weights["h"],
                               radius_px=radius, inner_px=inner, degree=degree,
                               quantisation_px=(results["v"].quantisation_px, results["h"].quantisation_px))
    t3 = time.perf_counter()
    notes = list(getattr(det, "notes", []))
    if fit.reasons:
        notes.append(f"projector pixels of {len(fit.reasons)} feature(s) not fitted: "
                     + "; ".join(f"id {det.ids[i]}: {m}" for i, m in list(fit.reasons.items())[:3])
                     + (" ..." if len(fit.reasons) > 3 else ""))
    sigma = fit.sigma_point[fit.ok]
    say(f"  {name}: board on {used}, {len(det.ids)} features, {int(fit.ok.sum())} with projector pixels"
        + (f", median sigma_prj {np.median(sigma):.4f} px" if sigma.size else ""))
    return PoseObservation(name, np.asarray(det.ids), np.asarray(det.points_board, np.float64),
                           np.asarray(det.q, np.float64), fit.q_prj, fit.sigma_point, used, notes,
                           {"unwrap": t1 - t0, "detect": t2 - t1, "phase_fit": t3 - t2},
                           (shape[1], shape[0]), image.astype(np.float32) if keep_image else None,
                           fit.dq_prj_dq_cam)


@dataclass
class CaptureObservations:
    """Observations of a capture session plus what happened per pose."""

    observations: Observations
    poses: list
    skipped: dict
    session: Capture
    seconds: float = 0.0

    def summary(self) -> dict:
        return {"folder": str(self.session.folder), "preset": self.session.preset,
                "board": self.session.board.to_dict(),
                "poses_used": [p.name for p in self.poses], "poses_skipped": dict(self.skipped),
                "features": {p.name: int(len(p.ids)) for p in self.poses},
                "projector_points": {p.name: int(np.isfinite(p.q_prj).all(axis=1).sum()) for p in self.poses},
                "median_sigma_prj_px": {p.name: float(np.median(p.sigma_prj[np.isfinite(p.sigma_prj)]))
                                        if np.isfinite(p.sigma_prj).any() else None for p in self.poses},
                "board_image": {p.name: p.board_image for p in self.poses},
                "notes": {p.name: p.notes for p in self.poses if p.notes},
                "seconds": {"total": self.seconds,
                            **{k: float(sum(p.seconds.get(k, 0.0) for p in self.poses))
                               for k in ("unwrap", "detect", "phase_fit")}}}


def observations_from_captures(folder, *, capture_toml=None, method=None, strict: bool = False,
                               min_poses: int = 3, detector=None, degree: int = 2, keep_images: bool = False,
                               progress=None, camera=None) -> CaptureObservations:
    """Every pose of a capture folder -> :class:`CaptureObservations` (see the module docstring).
    Progress goes to the ``calib`` logger (or to ``progress``, a callable taking one line).
    ``camera``: a camera model (e.g. a first calibration's ``cal.system.camera``) for the lens-bias
    correction of circle centres (``calib.detect.circles.lens_centre_bias``); with the default
    detector only."""
    say = progress or log.info
    if camera is not None and detector is None:
        from . import detect_board

        def detector(image, board):
            return detect_board(image, board, camera=camera)
    t0 = time.perf_counter()
    session = read_session(folder, capture_toml)
    say(f"capture {session.folder}: {len(session.poses)} pose(s), board {session.board.kind} "
        f"{session.board.rows}x{session.board.cols}, preset {session.preset}")
    poses, skipped = [], {}
    for i, (name, pose_dir) in enumerate(session.poses):
        say(f"pose {i + 1}/{len(session.poses)}: {name}")
        try:
            poses.append(observe_pose(session, name, pose_dir, method=method, detector=detector, degree=degree,
                                      keep_image=keep_images, progress=say))
        except (ValueError, OSError) as exc:     # CaptureError, UnwrapError, DetectionError, missing files
            if strict:
                raise CaptureError(f"pose {name}: {exc}") from None
            skipped[name] = str(exc)
            (progress or log.warning)(f"  {name}: skipped: {exc}")   # a warning: -q still shows it
    if len(poses) < min_poses:
        why = "; ".join(f"{k}: {v}" for k, v in skipped.items())
        raise ObservationError(f"{session.folder}: {len(poses)} usable pose(s), need >= {min_poses}"
                               + (f" (skipped: {why})" if why else ""))
    sizes = sorted({p.image_size for p in poses})
    if len(sizes) != 1:
        raise CaptureError(f"{session.folder}: poses differ in image size: {sizes}")
    cam_size = session.camera_size or sizes[0]
    if session.projector_size is None:
        raise CaptureError(f"{session.toml}: [projector] size missing")
    obs = Observations([p.view() for p in poses], {"camera": tuple(cam_size), "projector": tuple(session.projector_size)},
                       source=str(session.folder))
    return CaptureObservations(obs, poses, skipped, session, time.perf_counter() - t0)

