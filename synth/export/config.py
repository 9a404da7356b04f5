"""The export config (TOML): how many samples, which system, patterns, scenes and effect ranges.

Every key is optional except ``[export] samples``; unknown keys and impossible ranges raise
:class:`ExportConfigError` naming the key. A range is ``[lo, hi]`` (drawn uniformly per sample)
or one number (fixed); an effect whose range is absent or zero is not simulated at all (the
render plan of each sample says so)::

    [export]
    samples = 1000                # required
    seed = 0
    min_object_fraction = 0.05    # a draw whose objects cover less of the image is redrawn
    max_redraws = 20
    min_modulation = 0.02         # valid pixels: modulation above this fraction of full scale

    [system]
    file = "calibration.json"     # default: the built-in system; relative to this file
    ideal = false
    perturb = "none"              # or "posterior": draw the system from the calibration's covariance

    [patterns]
    orientations = ["v", "h"]
    frequencies = [1, 47, 48]     # periods across the pattern (1 must be there for the label check)
    steps = 12                    # or one per frequency
    A = 0.5
    B = 0.5

    [scene]
    objects = [1, 4]              # objects per sample
    mesh_dir = "../../../shared/data/meshes"   # relative to this file
    meshes = ["stanford-bunny.obj", "spot.obj"]
    mesh_fraction = 0.6           # chance that an object is a mesh (else procedural)
    procedural = ["sphere", "blobs", "heightfield", "steps", "plane"]
    size_mm = [50, 130]           # largest extent of an object
    depth_mm = [-80, 80]          # object centre along the camera axis, from the world origin's depth
    background = 0.7              # chance of a background plane
    background_gap_mm = [20, 120] # behind the farthest object centre
    background_tilt_deg = [0, 25]
    albedo = [0.3, 0.95]
    texture = 0.5                 # chance that an object has an albedo texture
    texture_contrast = [0.1, 0.6]
    layouts = ["free"]            # drawn uniformly per sample: "free" | "wall" | "table" (synth.export.layouts)
    wall_depth_mm = [20, 120]     # wall / table: the wall behind the farthest object centre
    wall_gap_mm = [2, 60]         # wall: object's nearest point to the wall
    wall_tilt_deg = [0, 50]
    wall_albedo = [0.5, 0.95]     # wall and table top
    table_elevation_deg = [15, 50]
    table_wall = 0.5              # chance of a wall behind the table

    [effects]                     # ranges; absent or 0 = not simulated
    exposure = [0.5, 0.9]
    ambient = [0, 0.1]
    vignetting = [0, 0.3]
    projector_gamma = [1, 1]
    noise = {full_well_e = [3000, 20000], read_noise_e = [2, 10]}
    projector_defocus = {aperture_mm = [0, 6], focus_offset_mm = [-150, 150]}
    camera_defocus = {aperture_mm = [0, 6], focus_offset_mm = [-150, 150], samples = [16, 32]}
                                  # samples: thin-lens aperture points (synth.effects.thin_lens), a whole
                                  # number or range; absent / 0: the Gaussian blur. A device whose blur
                                  # disc stays under THIN_LENS_MIN_DISC_PX everywhere gets the blur
                                  # (synth.export.defocus_model; params "defocus" says which ran)
    global_illumination = {subsurface = [0, 0.5], scatter_mm = [0.5, 4], interreflection = [0, 0.1],
                           interreflection_mm = [20, 60]}
    interreflection = {chance = 0.9, bounces = [1, 2], patch_px = [32, 48]}  # physically based
    frame_jitter = {offset = [0, 0.03], gain = [0, 0.01]}   # per-frame fluctuation: the standard
                                  # deviations drawn per sample (fractions of the background), the
                                  # frames' values from a drawn seed (synth.effects.frame_jitter)
    bits = 8
    shadows = "auto"

    [output]
    codec = "gzip-1"              # "gzip-N" (N = 1..9; "gzip" = 4) | "lzf" | "none"
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from unwrap.strict import apply_overrides, check_table, read_toml_text

from ..errors import ExportConfigError, SynthError  # noqa: F401  (ExportConfigError re-exported)


PROCEDURAL = ("sphere", "blobs", "heightfield", "steps", "plane")
LAYOUTS = ("free", "wall", "table")
#: scene keys of the wall / table layouts (left out of to_dict with the free layout alone, so the
#: configs made before layouts existed keep their fingerprint)
_LAYOUT_KEYS = ("layouts", "wall_depth_mm", "wall_gap_mm", "wall_tilt_deg", "wall_albedo", "table_elevation_deg",
                "table_wall")
CODECS = ("lzf", "gzip", "none") + tuple(f"gzip-{i}" for i in range(1, 10))


@dataclass(frozen=True)
class Range:
    """Uniform range [lo, hi] (lo == hi: fixed). ``off``: the effect is not simulated."""

    lo: float
    hi: float

    @property
    def off(self) -> bool:
        return self.lo == 0 and self.hi == 0

    def draw(self, rng) -> float:
        return self.lo if self.lo == self.hi else float(rng.uniform(self.lo, self.hi))

    def to_list(self):
        return [self.lo, self.hi]


ZERO = Range(0.0, 0.0)


@dataclass(frozen=True)
class ExportConfig:
    """The resolved export config (frozen; built by :func:`config_from_dict` from the TOML)."""

    samples: int
    seed: int = 0
    min_object_fraction: float = 0.05
    max_redraws: int = 20
    min_modulation: float = 0.02
    system_file: tuple = ()
    ideal: bool = False
    perturb: str = "none"
    orientations: tuple = ("v", "h")
    frequencies: tuple = (1.0, 47.0, 48.0)
    steps: tuple = (12, 12, 12)
    A: float = 0.5
    B: float = 0.5
    objects: tuple = (1, 4)
    meshes: tuple = ()
    mesh_fraction: float = 0.6
    procedural: tuple = PROCEDURAL
    size_mm: Range = Range(50.0, 130.0)
    depth_mm: Range = Range(-80.0, 80.0)
    background: float = 0.7
    background_gap_mm: Range = Range(20.0, 120.0)
    background_tilt_deg: Range = Range(0.0, 25.0)
    albedo: Range = Range(0.3, 0.95)
    texture: float = 0.5
    texture_contrast: Range = Range(0.1, 0.6)
    layouts: tuple = ("free",)
    wall_depth_mm: Range = Range(20.0, 120.0)
    wall_gap_mm: Range = Range(2.0, 60.0)
    wall_tilt_deg: Range = Range(0.0, 50.0)
    wall_albedo: Range = Range(0.5, 0.95)
    table_elevation_deg: Range = Range(15.0, 50.0)
    table_wall: float = 0.5
    effects: dict = field(default_factory=dict)  # name -> Range or {sub: Range}; plus bits, shadows
    codec: str = "gzip-1"
    text: str = ""
    base_dir: Path = Path(".")

    def to_dict(self) -> dict:
        """The resolved config as JSON-able values (stored in every file)."""
        def conv(v):
            if isinstance(v, Range):
                return v.to_list()
            if isinstance(v, dict):
                return {k: conv(x) for k, x in v.items()}
            if isinstance(v, (tuple, list)):
                return [conv(x) for x in v]
            if isinstance(v, Path):
                return str(v)
            return v
        skip = {"text", "base_dir"} | (set(_LAYOUT_KEYS) if self.layouts == ("free",) else set())
        return {k: conv(v) for k, v in self.__dict__.items() if k not in skip}  # free layout: as before layouts


# -- validation helpers --------------------------------------------------------------------------

def _fail(key, msg):
    raise ExportConfigError(f"{key}: {msg}")


def _num(v, key, lo=None, hi=None, integer=False):
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        _fail(key, f"expected a {'whole ' if integer else ''}number, got {v!r}")
    if integer and int(v) != v:
        _fail(key, f"expected a whole number, got {v!r}")
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        _fail(key, f"{v!r} outside [{lo}, {hi}]")
    return int(v) if integer else float(v)


def _range(v, key, lo=None, hi=None) -> Range:
    """A number or [lo, hi] within [lo, hi] bounds -> Range (names the key on failure)."""
    if isinstance(v, (list, tuple)):
        if len(v) != 2:
            _fail(key, f"expected a number or a range [lo, hi], got {v!r}")
        a, b = (_num(x, key, lo, hi) for x in v)
        if a > b:
            _fail(key, f"impossible range [{a}, {b}] (lo > hi)")
        return Range(a, b)
    a = _num(v, key, lo, hi)
    return Range(a, a)


def _prob(v, key):
    return _num(v, key, 0.0, 1.0)


#: effect name -> (sub-keys or None, bounds (lo, hi)) of its ranges
_EFFECT_RANGES = {
    "exposure": (None, (0.0, 10.0)),
    "ambient": (None, (0.0, 1.0)),
    "vignetting": (None, (0.0, 1.0)),
    "projector_gamma": (None, (0.05, 10.0)),
    "gain": (None, (0.0, 10.0)),
    "noise": ({"full_well_e": (1.0, 1e9), "read_noise_e": (0.0, 1e6)}, None),
    "projector_defocus": ({"aperture_mm": (0.0, 100.0), "focus_offset_mm": (-1e4, 1e4), "samples": (0.0, 1024.0)},
                          None),
    "camera_defocus": ({"aperture_mm": (0.0, 100.0), "focus_offset_mm": (-1e4, 1e4), "samples": (0.0, 1024.0)},
                       None),
    "global_illumination": ({"subsurface": (0.0, 1.0), "scatter_mm": (1e-3, 1e3), "interreflection": (0.0, 1.0),
                             "interreflection_mm": (1e-3, 1e4)}, None),
    "interreflection": ({"chance": (0.0, 1.0), "bounces": (1.0, 2.0), "patch_px": (0.5, 256.0)}, None),
    "frame_jitter": ({"offset": (0.0, 1.0), "gain": (0.0, 1.0)}, None),
}
_EFFECT_DEFAULTS = {"exposure": Range(0.8, 0.8)}
_SUB_REQUIRED = {"noise": "full_well_e", "projector_defocus": "aperture_mm", "camera_defocus": "aperture_mm",
                 "global_illumination": None, "interreflection": "chance", "frame_jitter": None}

_RANGE = float | tuple[float, ...]
#: The TOML's layout (section -> key -> type) that the strict reader (unwrap.strict) checks first.
SCHEMA = {
    "export": {"samples": int, "seed": int, "min_object_fraction": float, "max_redraws": int, "min_modulation": float},
    "system": {"file": str | tuple[str, ...], "ideal": bool, "perturb": str},
    "patterns": {"orientations": tuple[str, ...], "frequencies": tuple[float, ...], "steps": int | tuple[int, ...],
                 "A": float, "B": float},
    "scene": {"objects": int | tuple[int, ...], "mesh_dir": str, "meshes": tuple[str, ...], "mesh_fraction": float,
              "procedural": tuple[str, ...], "size_mm": _RANGE, "depth_mm": _RANGE, "background": float,
              "background_gap_mm": _RANGE, "background_tilt_deg": _RANGE, "albedo": _RANGE, "texture": float,
              "texture_contrast": _RANGE, "layouts": tuple[str, ...], "wall_depth_mm": _RANGE,
              "wall_gap_mm": _RANGE, "wall_tilt_deg": _RANGE, "wall_albedo": _RANGE,
              "table_elevation_deg": _RANGE, "table_wall": float},
    "effects": {**{name: _RANGE if subs is None else dict.fromkeys(subs, _RANGE)
                   for name, (subs, _) in _EFFECT_RANGES.items()}, "bits": int, "shadows": str},
    "output": {"codec": str},
}


def _effects(d: dict) -> dict:
    out = dict(_EFFECT_DEFAULTS)
    for name, value in d.items():
        key = f"effects.{name}"
        if name == "bits":
            if value not in (8, 10, 12, 16):
                _fail(key, f"expected 8, 10, 12 or 16, got {value!r}")
            out[name] = value
            continue
        if name == "shadows":
            if value not in ("auto", "on", "off"):
                _fail(key, f"expected 'auto', 'on' or 'off', got {value!r}")
            out[name] = value
            continue
        subs, bounds = _EFFECT_RANGES[name]
        if subs is None:
            out[name] = _range(value, key, *bounds)
            continue
        need = _SUB_REQUIRED[name]
        if need and need not in value:
            _fail(f"{key}.{need}", "missing")
        out[name] = {k: _range(v, f"{key}.{k}", *subs[k]) for k, v in value.items()}
        n = out[name].get("samples")
        if n is not None and (n.lo != int(n.lo) or n.hi != int(n.hi)):
            _fail(f"{key}.samples", f"expected a whole number of aperture points or a range of them, "
                                    f"got {n.to_list()}")
    return out


def config_from_dict(d: dict, base_dir=Path("."), text: str = "", where: str = "export config") -> ExportConfig:
    """A parsed export TOML -> ExportConfig (ExportConfigError naming any bad key: an unknown one
    with the closest known key, a wrong type with the expected one, a value out of range)."""
    check_table(d, SCHEMA, where, ExportConfigError)
    ex = d.get("export", {})
    if "samples" not in ex:
        _fail("export.samples", "missing (how many samples to export)")
    fields = {"samples": _num(ex["samples"], "export.samples", 1, 1e9, integer=True), "text": text,
              "base_dir": Path(base_dir),
              "seed": _num(ex.get("seed", 0), "export.seed", 0, 2 ** 63 - 1, integer=True),
              "min_object_fraction": _num(ex.get("min_object_fraction", 0.05), "export.min_object_fraction", 0.0, 1.0),
              "max_redraws": _num(ex.get("max_redraws", 20), "export.max_redraws", 1, 10000, integer=True),
              "min_modulation": _num(ex.get("min_modulation", 0.02), "export.min_modulation", 0.0, 0.5)}
    fields.update(_system_section(d.get("system", {})))
    fields.update(_patterns_section(d.get("patterns", {})))
    fields.update(_scene_section(d.get("scene", {}), base_dir))
    fields["effects"] = _effects(d.get("effects", {}))
    fields["codec"] = d.get("output", {}).get("codec", "gzip-1")
    if fields["codec"] not in CODECS:
        _fail("output.codec", f"expected one of lzf, gzip, gzip-1..9, none; got {fields['codec']!r}")
    return ExportConfig(**fields)


def _system_section(sy: dict) -> dict:
    out = {}
    if "file" in sy:
        files = sy["file"] if isinstance(sy["file"], list) else [sy["file"]]
        out["system_file"] = tuple(str(f) for f in files)
    out["ideal"] = bool(sy.get("ideal", False))
    out["perturb"] = sy.get("perturb", "none")
    if out["perturb"] not in ("none", "posterior"):
        _fail("system.perturb", f"expected 'none' or 'posterior', got {out['perturb']!r}")
    if out["perturb"] == "posterior" and not out.get("system_file"):
        _fail("system.perturb", "'posterior' needs system.file (a calibration.json written by calib run)")
    return out


def _patterns_section(pa: dict) -> dict:
    o = pa.get("orientations", ["v", "h"])
    if not o or any(x not in ("v", "h") for x in o) or len(set(o)) != len(o):
        _fail("patterns.orientations", f"expected a list of distinct 'v' / 'h', got {o!r}")
    fr = pa.get("frequencies", [1, 47, 48])
    if not fr:
        _fail("patterns.frequencies", f"expected a non-empty list, got {fr!r}")
    fr = [_num(f, "patterns.frequencies", 1e-6, 127.0) for f in fr]
    if sorted(set(fr)) != fr:
        _fail("patterns.frequencies", f"expected strictly increasing frequencies, got {fr}")
    st = pa.get("steps", 12)
    st = [st] * len(fr) if not isinstance(st, list) else st
    if len(st) != len(fr):
        _fail("patterns.steps", f"{len(st)} step counts for {len(fr)} frequencies")
    out = {"orientations": tuple(o), "frequencies": tuple(fr),
           "steps": tuple(_num(n, "patterns.steps", 3, 1000, integer=True) for n in st),
           "A": _num(pa.get("A", 0.5), "patterns.A", 0.0, 1.0), "B": _num(pa.get("B", 0.5), "patterns.B", 0.0, 1.0)}
    if out["A"] - out["B"] < -1e-12 or out["A"] + out["B"] > 1 + 1e-12:
        _fail("patterns.A/B", f"A +- B = [{out['A'] - out['B']}, {out['A'] + out['B']}] must lie in [0, 1]")
    return out


def _scene_section(sc: dict, base_dir) -> dict:
    n = _range(sc.get("objects", [1, 4]), "scene.objects", 1, 32)
    if n.lo != int(n.lo) or n.hi != int(n.hi):
        _fail("scene.objects", f"expected whole numbers, got {n.to_list()}")
    mesh_dir = Path(base_dir) / sc.get("mesh_dir", ".")
    meshes = sc.get("meshes", [])
    out = {"objects": (int(n.lo), int(n.hi)), "meshes": tuple(str(mesh_dir / m) for m in meshes),
           "mesh_fraction": _prob(sc.get("mesh_fraction", 0.6 if meshes else 0.0), "scene.mesh_fraction")}
    if out["mesh_fraction"] > 0 and not meshes:
        _fail("scene.mesh_fraction", f"{out['mesh_fraction']} but scene.meshes is empty")
    proc = sc.get("procedural", list(PROCEDURAL))
    if any(p not in PROCEDURAL for p in proc):
        _fail("scene.procedural", f"expected a list of {list(PROCEDURAL)}, got {proc!r}")
    if not proc and out["mesh_fraction"] < 1:
        _fail("scene.procedural", "empty, but scene.mesh_fraction < 1 asks for procedural objects")
    out.update({
        "procedural": tuple(proc),
        "size_mm": _range(sc.get("size_mm", [50, 130]), "scene.size_mm", 1.0, 5000.0),
        "depth_mm": _range(sc.get("depth_mm", [-80, 80]), "scene.depth_mm", -5000.0, 5000.0),
        "background": _prob(sc.get("background", 0.7), "scene.background"),
        "background_gap_mm": _range(sc.get("background_gap_mm", [20, 120]), "scene.background_gap_mm", 0.0, 5000.0),
        "background_tilt_deg": _range(sc.get("background_tilt_deg", [0, 25]), "scene.background_tilt_deg", 0.0, 80.0),
        "albedo": _range(sc.get("albedo", [0.3, 0.95]), "scene.albedo", 0.0, 1.0),
        "texture": _prob(sc.get("texture", 0.5), "scene.texture"),
        "texture_contrast": _range(sc.get("texture_contrast", [0.1, 0.6]), "scene.texture_contrast", 0.0, 1.0)})
    lay = sc.get("layouts", ["free"])
    if not lay or any(x not in LAYOUTS for x in lay) or len(set(lay)) != len(lay):
        _fail("scene.layouts", f"expected a non-empty list of distinct {list(LAYOUTS)}, got {lay!r}")
    out.update({
        "layouts": tuple(lay),
        "wall_depth_mm": _range(sc.get("wall_depth_mm", [20, 120]), "scene.wall_depth_mm", 0.0, 5000.0),
        "wall_gap_mm": _range(sc.get("wall_gap_mm", [2, 60]), "scene.wall_gap_mm", 0.0, 5000.0),
        "wall_tilt_deg": _range(sc.get("wall_tilt_deg", [0, 50]), "scene.wall_tilt_deg", 0.0, 80.0),
        "wall_albedo": _range(sc.get("wall_albedo", [0.5, 0.95]), "scene.wall_albedo", 0.0, 1.0),
        "table_elevation_deg": _range(sc.get("table_elevation_deg", [15, 50]), "scene.table_elevation_deg", 5.0, 85.0),
        "table_wall": _prob(sc.get("table_wall", 0.5), "scene.table_wall")})
    return out


def load_config(path, overrides=()) -> ExportConfig:
    """Read an export TOML, then ``section.key=value`` ``overrides`` (ExportConfigError on any
    invalid key, naming it)."""
    path = Path(path)
    text, d = read_toml_text(path, ExportConfigError, "export config")
    check_table(d, SCHEMA, f"export config {path}", ExportConfigError)
    for item in overrides or ():
        check_table(apply_overrides({}, [item], ExportConfigError), SCHEMA, "overrides", ExportConfigError)
    if overrides:
        text += "\n# overrides\n" + "".join(f"# {item}\n" for item in overrides)
    return config_from_dict(apply_overrides(d, overrides, ExportConfigError), path.parent, text, f"export config {path}")

