"""Point observations of a planar board by the camera and the projector (inverse camera).

One ``ViewObservations`` per board pose: the board points (board frame, mm, z = 0), the camera
pixels and the projector pixels of the same points (NaN where a device did not see a point),
and optional per-point standard deviations (px). ``Observations`` holds the views and both
device image sizes; readers for the Bouguet ``.mat`` pair and the observation JSON live here.

Observation JSON schema (documented in docs/calib.md)::

    {"camera_size": [640, 480], "projector_size": [912, 1140],
     "views": [{"name": "pose_00",
                "points_board": [[x, y, 0], ...],          # mm, board frame
                "q_cam": [[u, v], ...] | null,              # px; null entries = not seen
                "q_prj": [[u, v], ...] | null,
                "sigma_cam": [s, ...] (optional, px), "sigma_prj": [s, ...] (optional, px),
                "dprj_dcam": [[[du/dx, du/dy], [dv/dx, dv/dy]] | null, ...] (optional)}]}

``dprj_dcam`` is the local derivative of the projector pixel read at a camera pixel with respect
to that camera pixel (projector px per camera px, from the phase fit around the feature). With
it, the adjustment knows that a camera detection error ``e`` moves the projector pixel by
``dprj_dcam @ e`` (see ``calib.adjustment.problem``, "camera error transfer").
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from unwrap.safe_output import write_text

from .errors import ObservationError

DEVICES = ("camera", "projector")


def _points(a, shape_tail, name):
    try:
        a = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ObservationError(f"{name}: cannot be read as numbers ({exc})") from None
    if a.ndim != 2 or a.shape[1] != shape_tail:
        raise ObservationError(f"{name}: expected shape (N, {shape_tail}), got {a.shape}")
    return a


@dataclass
class ViewObservations:
    """One board pose.

    - points_board: (N, 3) mm, board frame (z = 0 for a flat board).
    - q: {"camera": (N, 2), "projector": (N, 2)} pixels, NaN rows = not observed.
    - sigma: same keys, (N,) px standard deviation per point (default 1: equal weights).
    - ids: (N,) int feature ids (board numbering), for reports.
    - dprj_dcam: optional (N, 2, 2) ``d q_prj / d q_cam`` at each feature (NaN rows: unknown).
    """

    points_board: np.ndarray
    q: dict
    sigma: dict = field(default_factory=dict)
    ids: np.ndarray | None = None
    name: str = ""
    dprj_dcam: np.ndarray | None = None

    def __post_init__(self):
        label = self.name or "view"
        self.points_board = _points(self.points_board, 3, f"{label}.points_board")
        if not np.all(np.isfinite(self.points_board)):
            raise ObservationError(f"{label}.points_board: non-finite values")
        n = len(self.points_board)
        q = {}
        for dev, val in self.q.items():
            if dev not in DEVICES:
                raise ObservationError(f"{label}: unknown device {dev!r}; expected {DEVICES}")
            if val is None:
                continue
            a = _points(val, 2, f"{label}.q_{dev[:3]}")
            if len(a) != n:
                raise ObservationError(f"{label}.q_{dev[:3]}: {len(a)} points, points_board has {n}")
            q[dev] = a
        self.q = q
        sig = {}
        for dev in q:
            s = self.sigma.get(dev)
            s = np.ones(n) if s is None else np.asarray(s, dtype=np.float64).reshape(-1)
            if s.shape != (n,) or not np.all(np.isfinite(s) & (s > 0) | ~np.isfinite(q[dev][:, 0])):
                raise ObservationError(f"{label}.sigma_{dev[:3]}: expected {n} positive finite values (px)")
            sig[dev] = s
        self.sigma = sig
        self.ids = np.arange(n) if self.ids is None else np.asarray(self.ids, dtype=int)
        if self.dprj_dcam is not None:
            try:
                g = np.asarray(self.dprj_dcam, dtype=np.float64)
            except (TypeError, ValueError):
                raise ObservationError(f"{label}.dprj_dcam: cannot be read as numbers") from None
            if g.shape != (n, 2, 2):
                raise ObservationError(f"{label}.dprj_dcam: expected shape ({n}, 2, 2), got {g.shape}")
            g = np.where(np.all(np.isfinite(g), axis=(1, 2))[:, None, None], g, np.nan)
            self.dprj_dcam = g

    def seen(self, device: str) -> np.ndarray:
        """(N,) bool: points this device observed."""
        if device not in self.q:
            return np.zeros(len(self.points_board), bool)
        return np.all(np.isfinite(self.q[device]), axis=-1)


@dataclass
class Observations:
    """All views plus device sizes ``{"camera": (W, H), "projector": (W, H)}``."""

    views: list
    sizes: dict
    source: str = ""

    def devices(self) -> list[str]:
        return [d for d in DEVICES if any(v.seen(d).any() for v in self.views)]

    def count(self, device: str) -> int:
        return int(sum(v.seen(device).sum() for v in self.views))

    def subset(self, view_indices) -> "Observations":
        return Observations([self.views[i] for i in view_indices], dict(self.sizes), self.source)

    def only(self, device: str) -> "Observations":
        """The same views with one device's observations only."""
        views = [ViewObservations(v.points_board, {device: v.q[device]}, {device: v.sigma[device]},
                                  v.ids, v.name) for v in self.views if device in v.q]
        return Observations(views, {device: self.sizes[device]}, self.source)


def from_bouguet(camera_path=None, projector_path=None) -> Observations:
    """Observations from a Bouguet toolbox result pair (either may be None)."""
    from .io.bouguet import read_bouguet

    results = {d: read_bouguet(p) for d, p in (("camera", camera_path), ("projector", projector_path))
               if p is not None}
    if not results:
        raise ObservationError("no observation file given")
    counts = {d: len(r.points_board) for d, r in results.items()}
    if len(set(counts.values())) != 1:
        raise ObservationError(f"the files hold different numbers of views {counts}: not one session")
    first = next(iter(results.values()))
    views = []
    for i in range(len(first.points_board)):
        X = first.points_board[i]
        q = {}
        for d, r in results.items():
            if not r.active[i]:
                continue
            if not np.allclose(r.points_board[i], X):
                raise ObservationError(f"view {i + 1}: the board points of {r.path} differ from "
                                       f"{first.path}; cannot pair them")
            q[d] = r.points_px[i]
        if q:
            views.append(ViewObservations(X, q, name=f"view_{i + 1}"))
    sizes = {d: r.size for d, r in results.items()}
    return Observations(views, sizes, source=" + ".join(str(r.path) for r in results.values()))


def read_observations_json(path) -> Observations:
    """Read the observation JSON (schema in the module docstring)."""
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise ObservationError(f"{path}: no such file") from None
    except json.JSONDecodeError as exc:
        raise ObservationError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(d, dict) or "views" not in d:
        raise ObservationError(f"{path}: expected an object with 'views'")
    sizes = {}
    for dev in DEVICES:
        key = f"{dev}_size"
        if key in d:
            sizes[dev] = tuple(int(v) for v in d[key])
    views = []
    for i, v in enumerate(d["views"]):
        name = v.get("name", f"view_{i + 1}")
        q, sig = {}, {}
        for dev, short in (("camera", "cam"), ("projector", "prj")):
            if v.get(f"q_{short}") is not None:
                if dev not in sizes:
                    raise ObservationError(f"{path}: {name} has q_{short} but no {dev}_size is given")
                q[dev] = np.array([[np.nan, np.nan] if p is None else p for p in v[f"q_{short}"]], float)
                if v.get(f"sigma_{short}") is not None:
                    sig[dev] = v[f"sigma_{short}"]
        g = v.get("dprj_dcam")
        if g is not None:
            g = [[[np.nan] * 2] * 2 if e is None else e for e in g]
        views.append(ViewObservations(v.get("points_board", []), q, sig, v.get("ids"), name, g))
    return Observations(views, sizes, source=str(path))


def write_observations_json(obs: Observations, path) -> Path:
    """Write observations in the JSON schema (NaN rows become null)."""
    out = {f"{d}_size": list(s) for d, s in obs.sizes.items()}
    out["views"] = []
    for v in obs.views:
        e = {"name": v.name, "points_board": v.points_board.tolist(), "ids": v.ids.tolist()}
        for dev, short in (("camera", "cam"), ("projector", "prj")):
            if dev in v.q:
                e[f"q_{short}"] = [None if not np.all(np.isfinite(p)) else p.tolist() for p in v.q[dev]]
                e[f"sigma_{short}"] = v.sigma[dev].tolist()
        if v.dprj_dcam is not None:
            e["dprj_dcam"] = [None if not np.all(np.isfinite(g)) else g.tolist() for g in v.dprj_dcam]
        out["views"].append(e)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, json.dumps(out, indent=1) + "\n")
    return path
