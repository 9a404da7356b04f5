"""Which defocus model a sample of the export runs: the thin lens only where it is worth its cost.

A defocus table of the export config with ``samples`` (a whole number or a range, drawn per sample
by synth.export.scenes) asks for the thin lens of synth.effects.thin_lens: the mean of pinhole
renders from ``samples`` aperture points, with exact occlusion across outlines, where the
Gaussian blur of the finished image (the default) mixes what the lens centre sees across them.
Its cost grows about linearly with ``samples`` (every aperture point renders the whole pattern
stack, interreflection included), so, as everywhere in the renderer, only what the scene calls
for is simulated: a device whose blur disc stays under :data:`THIN_LENS_MIN_DISC_PX` of its own
pixels at every pixel it lights or sees gets the blur instead (there a mixed pixel mixes at most
half a pixel's width: within what the pixel-centre render and the blur already leave out).

The blur disc of a point at device depth z is ``c = aperture_mm * f_px * |1/z - 1/focus_mm|``
(synth.effects.spec.Defocus; ``sigma = c / 4``); it is read off the sample's lens-centre
geometry, which the export computes anyway (camera: the pixels that see a surface; projector:
the lit pixels, the larger of its two axes).

The sample's ``params`` record the choice under ``"defocus"`` (only for the devices whose table
has ``samples``, so the files of configs without it are unchanged), e.g.::

    "defocus": {"camera_defocus": {"samples": 16, "model": "thin lens", "max_disc_px": 5.8}}

``model``: ``"thin lens"`` (ran with ``samples`` aperture points), ``"blur"`` (``samples`` drawn
0, or the disc under the threshold) or ``"none"`` (no aperture drawn: no defocus at all). The drawn
``samples`` also stay in ``params["effects"]``.
"""
from __future__ import annotations

from dataclasses import replace

#: blur disc diameter (device pixels) below which the thin lens is not run
THIN_LENS_MIN_DISC_PX = 0.5

DEVICES = ("projector_defocus", "camera_defocus")


def max_disc_px(geometry, device: str) -> float:
    """Largest blur disc diameter (device px) over the pixels ``device`` defocus acts on: the
    camera's over the pixels that see a surface, the projector's over the lit ones; 0 where
    there are none or no defocus."""
    if device == "camera_defocus":
        sigma, mask = geometry.sigma_cam, geometry.hit
    else:
        sigma, mask = geometry.sigma_prj, geometry.lit
    if sigma is None or not bool(mask.any()):
        return 0.0
    return 4.0 * float(sigma[mask].max())


def choose_defocus_model(cfg, scene, geometry, params: dict, min_disc_px: float = THIN_LENS_MIN_DISC_PX):
    """``scene`` with the thin lens kept only on devices whose blur disc reaches ``min_disc_px``
    somewhere (module docstring); records the choice in ``params["defocus"]`` and a plan line
    in ``params["plan"]`` per device whose config table has ``samples``. Returns the scene."""
    record = {}
    eff = scene.effects
    for name in DEVICES:
        if "samples" not in cfg.effects.get(name, {}):
            continue
        dof = getattr(eff, name)
        if dof is None:
            record[name] = {"samples": 0, "model": "none", "max_disc_px": 0.0}
            continue
        disc = max_disc_px(geometry, name)
        model = "thin lens" if dof.samples > 0 and disc >= min_disc_px else "blur"
        record[name] = {"samples": int(dof.samples), "model": model, "max_disc_px": disc}
        if dof.samples > 0 and model == "blur":
            eff = replace(eff, **{name: replace(dof, samples=0)})
            params.setdefault("plan", []).append(
                f"{name.replace('_', ' ')}: blur instead of the thin lens (blur disc up to {disc:.3g} px "
                f"< {min_disc_px:g} px)")
    if record:
        params["defocus"] = record
    return scene if eff is scene.effects else replace(scene, effects=eff)


def sampled(scene) -> bool:
    """Whether ``scene`` renders with the thin lens (a defocus with ``samples`` >= 1)."""
    return any(d is not None and d.samples > 0 for d in (scene.effects.camera_defocus,
                                                          scene.effects.projector_defocus))
