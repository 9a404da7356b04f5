"""The optional effects a scene asks for (``[effects]`` of the scene TOML), validated.

Radiometry (linear camera value before gain, 1.0 = full scale):

    value = exposure * albedo * (ambient + p(u_p, v_p) * cos_p * (d_ref / d_p)^2) * vignetting

``p`` is the projected pattern value after projector gamma and defocus, ``cos_p`` the cosine
between the surface normal and the direction to the projector (Lambertian; 1 when shading is
"none"), ``d_p`` the distance to the projector centre (the inverse-square term is 1 when
``falloff`` is false), ``d_ref`` the reference distance (default: projector centre to world
origin). Then: global illumination (optional, synth.effects.global_illumination), camera defocus
(a blur, or the thin lens of synth.effects.thin_lens with ``samples``),
per-frame fluctuation (optional, synth.effects.frame_jitter), the PSF's tail,
Poisson-Gaussian noise (electrons), gain, saturation at full scale, the camera's response curve
(synth.effects.response), quantisation to ``bits``. Interreflection (optional, synth.effects.interreflection) adds
light that reaches a point from other surfaces, before the camera stages.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

from unwrap.strict import check_keys

from ..errors import SynthError


@dataclass(frozen=True)
class Defocus:
    """Thin-lens blur: a point at depth z (device frame, mm) blurs into a disc of diameter
    ``c = aperture_mm * f_px * |1/z - 1/focus_mm|`` pixels; we use the Gaussian with the disc's
    per-axis second moment, ``sigma = c / 4`` (a uniform disc of radius r has variance r^2/4 along
    each axis), interpolated between ``levels`` blur levels. Checked against Blender's thin-lens
    depth of field (tests/test_synth_reference.py).

    ``samples``: 0 (default), the Gaussian blur above (camera: of the finished image; projector:
    of the pattern); >= 1, the thin lens itself, as the average of pinhole renders from
    ``samples`` aperture points (synth.effects.thin_lens: exact occlusion across outlines for the
    camera, penumbrae and exact per-point focus for the projector)."""

    aperture_mm: float
    focus_mm: float
    levels: int = 6
    samples: int = 0


@dataclass(frozen=True)
class Noise:
    """Poisson shot noise on ``full_well_e`` electrons at full scale plus Gaussian read noise."""

    full_well_e: float = 10000.0
    read_noise_e: float = 5.0
    seed: int = 0


@dataclass(frozen=True)
class GlobalIllumination:
    """Subsurface scattering and interreflections (synth.effects.global_illumination): a fraction
    ``subsurface`` of the direct light leaves the object after a Gaussian spread of
    ``scatter_mm`` over its surface; a fraction ``interreflection`` comes back from the surrounding
    surfaces after a spread of ``interreflection_mm``. ``per_object``: ((fraction, scatter_mm), ...)
    per scene object (its material), overriding the first two."""

    subsurface: float = 0.0
    scatter_mm: float = 2.0
    interreflection: float = 0.0
    interreflection_mm: float = 40.0
    per_object: tuple = ()

    def materials(self, n_objects: int) -> list:
        """(fraction, scatter_mm) of each of ``n_objects`` objects."""
        return [self.per_object[i] if i < len(self.per_object) else (self.subsurface, self.scatter_mm)
                for i in range(n_objects)]

    @property
    def active(self) -> bool:
        return self.interreflection > 0 or self.subsurface > 0 or any(s > 0 for s, _ in self.per_object)


@dataclass(frozen=True)
class Interreflection:
    """Physically based diffuse interreflection from the scene's own geometry
    (synth.effects.interreflection): surface patches lit by the projector (sampled through a grid of
    projector rays, ``patch_px`` projector pixels apart, refined ``refine`` x ``refine`` times
    where a receiver is closer than ``near`` patch sizes) send their direct light to every
    camera-visible point with the Lambertian form factor and exact visibility; ``bounces`` 1 or
    2 (the second gathers the first bounce at the same patches). ``mesh_visibility``: test every
    pair against the scene's meshes (synth.effects._segment_kernel: a uniform grid over the triangles, a
    mesh above 8000 triangles replaced by its vertex clustering at 1/30 of its extent; ~6x the
    time of the effect on the bunny scene; default); off, meshes block no indirect light (an
    over-estimate where a mesh shadows its own indirect light)."""

    bounces: int = 1
    patch_px: float = 32.0
    refine: int = 4
    near: float = 2.0
    mesh_visibility: bool = True
    #: with the thin lens (``*_defocus.samples``): "shared", the lens centre's indirect light looked
    #: up at every aperture point's surface points (synth.effects.lens_indirect), or "exact", a
    #: transport per aperture point
    thin_lens: str = "shared"


@dataclass(frozen=True)
class PsfTail:
    """The camera PSF's wide tail (synth.effects.response): a fraction ``fraction`` of the light
    on the sensor plane spread by a Gaussian of ``sigma_px`` camera pixels."""

    fraction: float
    sigma_px: float


@dataclass(frozen=True)
class FrameJitter:
    """Per-frame intensity fluctuation (synth.effects.frame_jitter): per frame an additive offset
    of standard deviation ``offset`` and a gain of standard deviation ``gain``, both fractions of
    the stack's background, drawn from ``seed``."""

    offset: float = 0.0
    gain: float = 0.0
    seed: int = 0

    @property
    def active(self) -> bool:
        return self.offset > 0 or self.gain > 0


@dataclass(frozen=True)
class Effects:
    exposure: float = 0.8
    shading: str = "lambert"          # "lambert" | "none"
    falloff: bool = True
    reference_distance_mm: float | None = None
    ambient: float = 0.0
    shadows: str = "auto"             # "auto" | "on" | "off"
    camera_distortion: bool = True
    projector_distortion: bool = True
    projector_defocus: Defocus | None = None
    camera_defocus: Defocus | None = None
    projector_gamma: float = 1.0
    camera_gamma: float = 1.0           # camera response: output = clip(gain v, 0, saturation)^camera_gamma
    camera_psf_tail: PsfTail | None = None
    gain: float = 1.0
    saturation: float = 1.0
    noise: Noise | None = None
    global_illumination: GlobalIllumination | None = None
    interreflection: Interreflection | None = None
    frame_jitter: FrameJitter | None = None
    bits: int = 8
    vignetting: float = 0.0           # strength: factor 1 - s * (1 - cos^4 theta)
    fringe_sampling: str = "analytic"  # "analytic" | "bilinear" | "nearest"
    image_sampling: str = "nearest"    # "nearest" (DMD pixels) | "bilinear"
    A: float = 0.5
    B: float = 0.5

    def to_dict(self) -> dict:
        return asdict(self)


_CHOICES = {"shading": ("lambert", "none"), "shadows": ("auto", "on", "off"),
            "fringe_sampling": ("analytic", "bilinear", "nearest"), "image_sampling": ("nearest", "bilinear")}


def _number(d, key, lo=None, hi=None, name="effects"):
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise SynthError(f"{name}.{key}: expected a number, got {v!r}")
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise SynthError(f"{name}.{key}: {v!r} outside [{lo}, {hi}]")
    return float(v)


def _sub(d, cls, key):
    if d is None or d is False:
        return None
    if not isinstance(d, dict):
        raise SynthError(f"effects.{key}: expected a table, got {d!r}")
    check_keys(d, cls.__dataclass_fields__, "scene", SynthError, prefix=f"effects.{key}.")
    kw = {}
    for k in d:
        if k == "samples":
            if isinstance(d[k], bool) or not isinstance(d[k], int) or not 0 <= d[k] <= 1024:
                raise SynthError(f"effects.{key}.samples: expected an integer in [0, 1024], got {d[k]!r}")
            kw[k] = d[k]
        elif k in ("levels", "seed"):
            if not isinstance(d[k], int) or d[k] < (2 if k == "levels" else 0):
                raise SynthError(f"effects.{key}.{k}: expected an integer >= {2 if k == 'levels' else 0}, got {d[k]!r}")
            kw[k] = d[k]
        else:
            kw[k] = _number(d, k, 0.0, None, f"effects.{key}")
    try:
        out = cls(**kw)
    except TypeError as exc:
        raise SynthError(f"effects.{key}: {exc}") from None
    if cls is Defocus and out.focus_mm <= 0:
        raise SynthError(f"effects.{key}.focus_mm: expected > 0, got {out.focus_mm}")
    if cls is Noise and out.full_well_e <= 0:
        raise SynthError(f"effects.{key}.full_well_e: expected > 0, got {out.full_well_e}")
    return out


def _global_illumination(d) -> GlobalIllumination | None:
    from .global_illumination import validate_materials

    if d is None or d is False:
        return None
    d = dict(d) if isinstance(d, dict) else d
    if not isinstance(d, dict):
        raise SynthError(f"effects.global_illumination: expected a table, got {d!r}")
    per = validate_materials(d.pop("per_object", []))
    out = _sub(d, GlobalIllumination, "global_illumination") or GlobalIllumination()
    for k in ("subsurface", "interreflection"):
        if getattr(out, k) > 1:
            raise SynthError(f"effects.global_illumination.{k}: expected a fraction in [0, 1], got {getattr(out, k)}")
    for k in ("scatter_mm", "interreflection_mm"):
        if getattr(out, k) <= 0:
            raise SynthError(f"effects.global_illumination.{k}: expected > 0, got {getattr(out, k)}")
    return replace(out, per_object=per)


def _interreflection(d) -> Interreflection | None:
    if d is None or d is False:
        return None
    if d is True:
        return Interreflection()
    if not isinstance(d, dict):
        raise SynthError(f"effects.interreflection: expected a table or true, got {d!r}")
    check_keys(d, Interreflection.__dataclass_fields__, "scene", SynthError, prefix="effects.interreflection.")
    kw = {}
    for k, v in d.items():
        if k == "mesh_visibility":
            if not isinstance(v, bool):
                raise SynthError(f"effects.interreflection.mesh_visibility: expected true or false, got {v!r}")
            kw[k] = v
        elif k == "thin_lens":
            if v not in ("shared", "exact"):
                raise SynthError(f'effects.interreflection.thin_lens: expected "shared" or "exact", got {v!r}')
            kw[k] = v
        elif k in ("bounces", "refine"):
            lo, hi = (1, 2) if k == "bounces" else (1, 16)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise SynthError(f"effects.interreflection.{k}: expected an integer in [{lo}, {hi}], got {v!r}")
            kw[k] = v
        else:
            kw[k] = _number(d, k, 0.5 if k == "patch_px" else 1.0, 256.0, "effects.interreflection")
    return Interreflection(**kw)


def _psf_tail(d) -> PsfTail | None:
    if d is None or d is False:
        return None
    if not isinstance(d, dict):
        raise SynthError(f"effects.camera_psf_tail: expected a table, got {d!r}")
    check_keys(d, PsfTail.__dataclass_fields__, "scene", SynthError, prefix="effects.camera_psf_tail.")
    for k in PsfTail.__dataclass_fields__:
        if k not in d:
            raise SynthError(f"effects.camera_psf_tail.{k}: missing (fraction in [0, 1], sigma_px > 0)")
    out = PsfTail(_number(d, "fraction", 0.0, 1.0, "effects.camera_psf_tail"),
                  _number(d, "sigma_px", 0.0, 1000.0, "effects.camera_psf_tail"))
    if out.sigma_px <= 0:
        raise SynthError(f"effects.camera_psf_tail.sigma_px: expected > 0, got {out.sigma_px}")
    return out


def effects_from_table(d: dict | None) -> Effects:
    """``[effects]`` table -> Effects; unknown keys and bad values raise SynthError naming them."""
    d = dict(d or {})
    check_keys(d, Effects.__dataclass_fields__, "scene", SynthError, prefix="effects.")
    kw = {}
    for k, v in d.items():
        if k in _CHOICES:
            if v is True:
                v = {"shadows": "on"}.get(k, v)
            if v is False:
                v = {"shadows": "off", "shading": "none"}.get(k, v)
            if v not in _CHOICES[k]:
                raise SynthError(f"effects.{k}: expected one of {_CHOICES[k]}, got {v!r}")
            kw[k] = v
        elif k in ("falloff", "camera_distortion", "projector_distortion"):
            if not isinstance(v, bool):
                raise SynthError(f"effects.{k}: expected true or false, got {v!r}")
            kw[k] = v
        elif k in ("projector_defocus", "camera_defocus"):
            kw[k] = _sub(v, Defocus, k)
        elif k == "noise":
            kw[k] = _sub(v, Noise, k)
        elif k == "global_illumination":
            kw[k] = _global_illumination(v)
        elif k == "interreflection":
            kw[k] = _interreflection(v)
        elif k == "frame_jitter":
            kw[k] = _sub(v, FrameJitter, k)
            if kw[k] is not None and not (0 <= kw[k].offset <= 1 and 0 <= kw[k].gain <= 1):   # NaN too
                raise SynthError(f"effects.frame_jitter: offset and gain are fractions in [0, 1], got {v!r}")
        elif k == "bits":
            if v not in (8, 10, 12, 16):
                raise SynthError(f"effects.bits: expected 8, 10, 12 or 16, got {v!r}")
            kw[k] = v
        elif k == "reference_distance_mm":
            kw[k] = _number(d, k, 1e-6)
        elif k in ("projector_gamma", "camera_gamma"):
            kw[k] = _number(d, k, 0.05, 10)
        elif k == "camera_psf_tail":
            kw[k] = _psf_tail(v)
        elif k in ("ambient", "exposure", "gain", "saturation", "vignetting", "A", "B"):
            kw[k] = _number(d, k, 0.0, 1.0 if k in ("vignetting", "A", "B") else None)
    eff = Effects(**kw)
    if eff.A - eff.B < -1e-12 or eff.A + eff.B > 1 + 1e-12:
        raise SynthError(f"effects.A/B: the pattern A +- B = [{eff.A - eff.B}, {eff.A + eff.B}] must lie in [0, 1]")
    return eff
