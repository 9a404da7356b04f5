"""Scenes: the system (camera + projector models), objects with poses, the pattern sequence and
the effects, from a TOML file or built in Python.

TOML schema (every key optional unless marked; see docs/synth.md for the full reference)::

    [system]                      # default: calib.default_system() (the paper's real system)
    file = "calibration.json"     # any file calib.load_system reads, relative to the TOML
    ideal = false                 # drop skew and distortion (what Blender can represent)

    [[objects]]
    kind = "plane" | "board" | "sphere" | "mesh" | "heightfield" | "steps" | "blobs"
    name = "..."                  # default kind + index
    pose = {rotation_deg = [rx, ry, rz], t = [x, y, z]}    # or {R = [[...]], t = [...]}
    albedo = 0.8
    ...                           # kind-specific keys

    [patterns]
    A = 0.5
    B = 0.5
    [[patterns.sequence]]         # required: phase / gray / white / black / image entries
    kind = "phase"
    orientation = "both"
    frequencies = [1, 8, 48]
    steps = 12

    [effects]                     # synth.effects.spec.Effects
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calib.system import SystemModel, default_system
from unwrap.strict import check_keys, check_table, read_toml_text

from .boards import board_from_table
from ..effects.spec import Effects, effects_from_table
from ..errors import SynthError
from .meshes import blobs_heights, heightfield_mesh, load_mesh, steps_mesh
from .objects import Board, Mesh, Plane, SceneObject, Sphere
from .poses import parse_pose
from .sequence import PatternSpec, sequence_from_tables

#: The top level of a scene TOML (the strict reader, unwrap.strict, checks keys and types).
SCHEMA = {"system": {"file": str | tuple[str, ...], "ideal": bool}, "objects": tuple[dict, ...],
          "patterns": {"sequence": tuple[dict, ...], "A": float, "B": float}, "effects": dict, "name": str}

#: Default ball radius (mm): a 50.8 mm (2 in) standard sphere. The supplementary does not state
#: the size of the paper's ball; this is a common gauge-ball size, used unless a scene says.
DEFAULT_BALL_RADIUS_MM = 25.4


@dataclass
class Scene:
    """Everything a render needs. ``objects`` may be empty (an empty scene renders black)."""

    system: SystemModel
    objects: list
    patterns: list
    effects: Effects = field(default_factory=Effects)
    name: str = "scene"
    source_text: str = ""

    def __post_init__(self):
        names = [o.name for o in self.objects]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise SynthError(f"objects: duplicate names {dup}")
        if not self.patterns:
            raise SynthError("patterns: the sequence is empty")
        for p in self.patterns:
            if not isinstance(p, PatternSpec):
                raise SynthError(f"patterns: expected PatternSpec items, got {type(p).__name__}")


def ideal_system(system: SystemModel) -> SystemModel:
    """The system without skew and distortion (what a Blender twin represents):
    :meth:`calib.system.SystemModel.ideal`, kept under this name."""
    return system.ideal()


_OBJECT_KEYS = {
    "plane": {"size_mm"},
    "board": {"board"},
    "sphere": {"radius_mm"},
    "mesh": {"file", "scale", "size_mm", "center", "smooth"},
    "heightfield": {"heights", "file", "size_mm", "height_scale_mm", "smooth"},
    "steps": {"size_mm", "heights_mm", "resolution"},
    "blobs": {"size_mm", "resolution", "count", "amplitude_mm", "width_mm", "seed", "smooth"},
}


def object_from_table(d: dict, index: int, base_dir: Path = Path(".")) -> SceneObject:
    """One ``[[objects]]`` table -> a SceneObject (SynthError naming ``objects[i].key``)."""
    key = f"objects[{index}]"
    if not isinstance(d, dict) or "kind" not in d:
        raise SynthError(f"{key}: expected a table with a 'kind' ({', '.join(_OBJECT_KEYS)})")
    kind = d["kind"]
    if kind not in _OBJECT_KEYS:
        raise SynthError(f"{key}.kind: expected one of {sorted(_OBJECT_KEYS)}, got {kind!r}")
    allowed = _OBJECT_KEYS[kind] | {"kind", "name", "pose", "albedo"}
    check_keys(d, allowed, f"scene (kind {kind!r})", SynthError, prefix=f"{key}.")
    name = str(d.get("name", f"{kind}{index}"))
    R, t = parse_pose(d.get("pose"), f"{key}.pose")
    albedo = d.get("albedo", 0.8)
    if isinstance(albedo, bool) or not isinstance(albedo, (int, float)):
        raise SynthError(f"{key}.albedo: expected a number in [0, 1], got {albedo!r}")

    def num(k, default, lo=0.0):
        v = d.get(k, default)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v <= lo:
            raise SynthError(f"{key}.{k}: expected a number > {lo}, got {v!r}")
        return float(v)

    def pair(k, default):
        v = d.get(k, default)
        try:
            a = [float(x) for x in v]
            assert len(a) == 2 and min(a) > 0
        except (TypeError, ValueError, AssertionError):
            raise SynthError(f"{key}.{k}: expected [width, height] > 0, got {v!r}") from None
        return a

    try:
        if kind == "plane":
            return Plane(name, R, t, albedo, pair("size_mm", None) if "size_mm" in d else None)
        if kind == "board":
            return Board(name, R, t, board_from_table(d.get("board", {}), f"{key}.board"))
        if kind == "sphere":
            return Sphere(name, R, t, albedo, num("radius_mm", DEFAULT_BALL_RADIUS_MM))
        smooth = bool(d.get("smooth", kind != "steps"))
        if kind == "mesh":
            if "file" not in d:
                raise SynthError(f"{key}.file: missing (an OBJ, STL or PLY file)")
            V, F = load_mesh(base_dir / d["file"])
            if d.get("center", True):
                V = V - (V.min(0) + V.max(0)) / 2
            if "size_mm" in d:
                V = V * (num("size_mm", 1.0) / float((V.max(0) - V.min(0)).max()))
            else:
                V = V * num("scale", 1.0)
            return Mesh(name, R, t, V, F, albedo, smooth, source=str(d["file"]))
        size = pair("size_mm", [100.0, 100.0])
        if kind == "heightfield":
            if "heights" in d:
                H = np.asarray(d["heights"], dtype=np.float64)
            elif "file" in d:
                path = base_dir / d["file"]
                if path.suffix == ".npy":
                    H = np.load(path)
                else:
                    import cv2
                    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
                    if img is None:
                        raise SynthError(f"{key}.file: cannot read {path}")
                    H = img.astype(np.float64) / float(np.iinfo(img.dtype).max) * num("height_scale_mm", 10.0)
            else:
                raise SynthError(f"{key}: a heightfield needs 'heights' (2-D array, mm) or 'file'")
            V, F = heightfield_mesh(H, size)
        elif kind == "steps":
            V, F = steps_mesh(size, d.get("heights_mm", [0.0, 10.0, 20.0]), int(d.get("resolution", 2)))
        else:
            res = d.get("resolution", [200, 200])
            V, F = heightfield_mesh(blobs_heights(size, res, int(d.get("count", 8)), num("amplitude_mm", 10.0),
                                                  num("width_mm", 15.0), int(d.get("seed", 0))), size)
        return Mesh(name, R, t, V, F, albedo, smooth, source=kind)
    except SynthError as exc:
        msg = str(exc)
        raise SynthError(msg if msg.startswith(key) or msg.startswith("mesh file") else f"{key}: {msg}") from None


def scene_from_dict(d: dict, base_dir: Path = Path("."), name: str = "scene", source_text: str = "") -> Scene:
    """A parsed scene TOML (dict) -> Scene."""
    check_table(d, SCHEMA, "scene", SynthError)
    sys_d = d.get("system", {})
    if "file" in sys_d:
        from calib.io import load_system
        files = sys_d["file"] if isinstance(sys_d["file"], list) else [sys_d["file"]]
        system = load_system([base_dir / f for f in files])
    else:
        system = default_system()
    if sys_d.get("ideal", False):
        system = ideal_system(system)
    objs = d.get("objects", [])
    objects = [object_from_table(o, i, base_dir) for i, o in enumerate(objs)]
    pat = d.get("patterns")
    if not isinstance(pat, dict) or "sequence" not in pat:
        raise SynthError("patterns.sequence: missing (e.g. [[patterns.sequence]] kind = \"phase\" ...)")
    patterns = sequence_from_tables(pat["sequence"], system.projector.size, base_dir)
    eff_d = dict(d.get("effects", {}))
    for k in ("A", "B"):
        if k in pat:
            eff_d[k] = pat[k]
    effects = effects_from_table(eff_d)
    return Scene(system, objects, patterns, effects, str(d.get("name", name)), source_text)


def load_scene(path) -> Scene:
    """Read a scene TOML file (SynthError on any invalid key, naming it)."""
    path = Path(path)
    text, d = read_toml_text(path, SynthError, "scene file")
    return scene_from_dict(d, path.parent, path.stem, text)
