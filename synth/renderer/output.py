"""Writing renders: grey PNGs (8-bit, or 16-bit for 10/12/16-bit images, scaled to full range so
that every level stays distinct) and the ground truth as one HDF5 file.

HDF5 layout (``truth.h5``), shaped like the camera image (H, W), chunked and gzip-compressed:

- ``depth`` (float64 mm, camera-frame z, NaN: no surface), ``points_cam`` (H,W,3),
  ``normals_cam`` (H,W,3), ``u_p`` / ``v_p`` (float64 px, NaN: not projectable), ``albedo``,
  ``object_id`` (int16, -1: none);
- ``masks/object``, ``masks/shadow``, ``masks/outside_projector``, ``masks/lit`` (bool);
- per orientation ``v`` / ``h`` (DESIGN.md, written by :func:`unwrap.phase_io.write_phase_group`):
  ``phase`` (absolute phase of the highest frequency, rad, NaN where invalid), ``order`` (int32,
  -1 where invalid), ``valid``; and per frequency ``phase_f008``, ``order_f008``;
- attributes: ``system`` (calibration.json text), ``scene`` (scene TOML text), ``effects``,
  ``objects``, ``patterns``, ``render_plan`` (JSON), ``bits``, ``software``.
"""
from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from ..scenes.sequence import frequency_tag


def to_png_array(counts: np.ndarray, bits: int) -> np.ndarray:
    """Integer counts (H,W) of a ``bits``-bit image -> uint8 (8 bits) or uint16 scaled to 65535."""
    if bits <= 8:
        return counts.astype(np.uint8)
    top = (1 << bits) - 1
    return np.round(counts.astype(np.float64) * (65535.0 / top)).astype(np.uint16)


def write_pngs(result, out_dir, names=None) -> list:
    import cv2

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    imgs = result.images.numpy()
    paths = []
    for k, name in enumerate(names or result.names):
        p = out_dir / f"{name}.png"
        if not cv2.imwrite(str(p), to_png_array(imgs[k], result.bits)):
            raise OSError(f"cannot write {p}")
        paths.append(p)
    return paths


def write_truth_h5(result, scene, path) -> Path:
    """Write the ground truth of ``result`` (see the module docstring) to ``path``."""
    import h5py

    from calib.io.calibration_json import system_to_dict
    from unwrap.phase_io import write_phase_group
    from unwrap.safe_output import write_bytes

    g = result.geometry
    W, H = g.size
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    kw = dict(compression="gzip", compression_opts=4, shuffle=True)

    def img(x, *extra):
        return x.reshape(H, W, *extra).numpy()

    buf = io.BytesIO()   # built in memory, written atomically: a full disk leaves no truncated file
    with h5py.File(buf, "w") as f:
        def put(name, arr):
            arr = np.ascontiguousarray(arr)
            f.create_dataset(name, data=arr, chunks=(min(H, 64), min(W, 64)) + arr.shape[2:], **kw)

        put("depth", img(g.depth))
        put("points_cam", img(g.points_cam, 3))
        put("normals_cam", img(g.normals_cam, 3))
        put("u_p", img(g.u_p))
        put("v_p", img(g.v_p))
        put("albedo", img(g.albedo))
        put("object_id", img(g.object_id).astype(np.int16))
        put("masks/object", img(g.hit))
        put("masks/shadow", img(g.shadow))
        put("masks/outside_projector", img(g.hit & ~g.in_field))
        put("masks/lit", img(g.lit))
        for o, per_f in result.truth(scene.system.projector.size, scene.patterns).items():
            top = max(per_f)
            phase, order, valid = per_f[top]
            extra = {}
            for fr, (phase_f, order_f, _) in per_f.items():
                extra[f"phase_{frequency_tag(fr)}"] = phase_f
                extra[f"order_{frequency_tag(fr)}"] = order_f
            write_phase_group(f, o, phase, order=order, valid=valid, frequency=top, extra=extra,
                              attrs={"frequencies": list(per_f)}, chunks=(min(H, 64), min(W, 64)), **kw)
        f.attrs["system"] = json.dumps(system_to_dict(scene.system))
        f.attrs["scene"] = scene.source_text
        f.attrs["effects"] = json.dumps(scene.effects.to_dict())
        f.attrs["objects"] = json.dumps([o.describe() for o in scene.objects])
        f.attrs["patterns"] = json.dumps(result.names)
        f.attrs["render_plan"] = json.dumps(result.plan)
        f.attrs["bits"] = result.bits
        f.attrs["software"] = "sltwin synth"
        f.attrs["units"] = "mm, px, rad"
    return write_bytes(path, buf.getbuffer())


def write_render(result, scene, out_dir) -> dict:
    """PNGs + ``truth.h5`` into ``out_dir``; returns {"images": [...], "truth": path}."""
    out_dir = Path(out_dir)
    return {"images": write_pngs(result, out_dir), "truth": write_truth_h5(result, scene, out_dir / "truth.h5")}
