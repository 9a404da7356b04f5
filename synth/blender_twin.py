"""Build the same scene in Blender (Cycles, CPU) and render it, in a SUBPROCESS: the toolkit never
imports bpy itself. Used by the parity test and the benchmark.

The twin follows ../shared/docs/BLENDER-NOTES.md: the projector is a SPOT light of zero radius
whose node tree maps the light-space direction (Texture Coordinate Normal, x/z and y/z) through
a Mapping node (scale (-fx/W, -fy/H, 1), location ((cx+0.5)/W, (H-cy-0.5)/H, 0)) into the
pattern image (Non-Color, linear, CLIP); Lambertian surfaces, direct light only, view transform
Raw, dither 0, 1 point-sampled path per pixel (Blackman-Harris 0.01 px). Device poses go in as
``matrix_world = [R^T diag(1,-1,-1) | -R^T t]`` (metres). Skew and distortion are not
representable: use an ideal system (``synth.ideal_system``).

Radiometry: the spot is a point source of P/(4 pi) W/sr, so a Lambertian surface of albedo rho
shows ``rho/pi * P/(4 pi) * cos / d^2``; ``P = 4 pi^2 exposure d_ref^2`` (metres) matches our
``exposure * rho * cos * (d_ref/d)^2``.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

_SCRIPT = r'''
import json, math, sys, time
import numpy as np
import bpy
cfg = json.load(open(sys.argv[-1]))
bpy.ops.wm.read_factory_settings(use_empty=True)
sc = bpy.context.scene
sc.unit_settings.system = "METRIC"; sc.unit_settings.scale_length = 1.0
sc.render.engine = "CYCLES"
cy = sc.cycles
cy.device = "CPU"; cy.samples = 1; cy.use_adaptive_sampling = False; cy.use_denoising = False
cy.max_bounces = 0; cy.diffuse_bounces = 0; cy.glossy_bounces = 0; cy.transmission_bounces = 0
cy.pixel_filter_type = "BLACKMAN_HARRIS"; cy.filter_width = 0.01
sc.render.threads_mode = "FIXED"; sc.render.threads = cfg["threads"]
sc.render.resolution_x, sc.render.resolution_y = cfg["camera"]["size"]; sc.render.resolution_percentage = 100
sc.render.dither_intensity = 0.0
sc.view_settings.view_transform = "Raw"; sc.view_settings.look = "None"
sc.view_settings.exposure = 0.0; sc.view_settings.gamma = 1.0
sc.render.image_settings.file_format = "PNG"; sc.render.image_settings.color_mode = "BW"
sc.render.image_settings.color_depth = "16"
world = bpy.data.worlds.new("w"); sc.world = world; world.use_nodes = True
world.node_tree.nodes["Background"].inputs[1].default_value = 0.0

def pose_matrix(R, t):
    import mathutils
    R = np.asarray(R); t = np.asarray(t)
    M = np.eye(4)
    M[:3, :3] = R.T @ np.diag([1.0, -1.0, -1.0])
    M[:3, 3] = -R.T @ t / 1000.0
    return mathutils.Matrix(M.tolist())

cam_d = cfg["camera"]; W, H = cam_d["size"]; K = np.asarray(cam_d["K"])
cam = bpy.data.cameras.new("cam"); cam.sensor_fit = "HORIZONTAL"; cam.sensor_width = 36.0
cam.lens = K[0, 0] * 36.0 / W
sc.render.pixel_aspect_x = 1.0; sc.render.pixel_aspect_y = 1.0  # callers pass fx == fy
cam.shift_x = (W / 2 - (K[0, 2] + 0.5)) / W
cam.shift_y = ((K[1, 2] + 0.5) - H / 2) / W
cam.clip_start = 0.001; cam.clip_end = 100.0
co = bpy.data.objects.new("cam", cam); sc.collection.objects.link(co); sc.camera = co
co.matrix_world = pose_matrix(cam_d["R"], cam_d["t"])

prj = cfg["projector"]; Wp, Hp = prj["size"]; Kp = np.asarray(prj["K"])
light = bpy.data.lights.new("projector", "SPOT")
light.energy = cfg["power_w"]; light.shadow_soft_size = 0.0; light.spot_blend = 0.0
light.spot_size = math.radians(179.0)
if hasattr(light, "use_soft_falloff"): light.use_soft_falloff = False
light.use_nodes = True
nt = light.node_tree; nodes = nt.nodes; links = nt.links
for n in list(nodes):
    if n.type not in ("OUTPUT_LIGHT",): nodes.remove(n)
out = [n for n in nodes if n.type == "OUTPUT_LIGHT"][0]
tc = nodes.new("ShaderNodeTexCoord"); sep = nodes.new("ShaderNodeSeparateXYZ")
dx = nodes.new("ShaderNodeMath"); dx.operation = "DIVIDE"
dy = nodes.new("ShaderNodeMath"); dy.operation = "DIVIDE"
comb = nodes.new("ShaderNodeCombineXYZ"); mp = nodes.new("ShaderNodeMapping"); mp.vector_type = "POINT"
mp.inputs["Scale"].default_value = (-Kp[0, 0] / Wp, -Kp[1, 1] / Hp, 1.0)
mp.inputs["Location"].default_value = ((Kp[0, 2] + 0.5) / Wp, (Hp - Kp[1, 2] - 0.5) / Hp, 0.0)
tex = nodes.new("ShaderNodeTexImage"); tex.interpolation = "Linear"; tex.extension = "CLIP"
em = nodes.new("ShaderNodeEmission")
links.new(tc.outputs["Normal"], sep.inputs[0])
links.new(sep.outputs[0], dx.inputs[0]); links.new(sep.outputs[2], dx.inputs[1])
links.new(sep.outputs[1], dy.inputs[0]); links.new(sep.outputs[2], dy.inputs[1])
links.new(dx.outputs[0], comb.inputs[0]); links.new(dy.outputs[0], comb.inputs[1])
links.new(comb.outputs[0], mp.inputs["Vector"]); links.new(mp.outputs[0], tex.inputs["Vector"])
links.new(tex.outputs["Color"], em.inputs["Color"]); links.new(em.outputs[0], out.inputs[0])
img = bpy.data.images.new("pattern", Wp, Hp, float_buffer=True, is_data=True)
img.colorspace_settings.name = "Non-Color"
tex.image = img
lo = bpy.data.objects.new("projector", light); sc.collection.objects.link(lo)
lo.matrix_world = pose_matrix(prj["R"], prj["t"])

for i, o in enumerate(cfg["objects"]):
    V = np.asarray(o["vertices"]) / 1000.0; F = np.asarray(o["faces"])
    me = bpy.data.meshes.new(f"m{i}"); me.from_pydata(V.tolist(), [], F.tolist()); me.update()
    if o.get("smooth"):
        for p in me.polygons: p.use_smooth = True
    mat = bpy.data.materials.new(f"mat{i}"); mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (o["albedo"],) * 3 + (1.0,)
    bsdf.inputs["Roughness"].default_value = 1.0
    for key in ("Specular IOR Level", "Specular"):
        if key in bsdf.inputs: bsdf.inputs[key].default_value = 0.0
    me.materials.append(mat)
    ob = bpy.data.objects.new(f"o{i}", me); sc.collection.objects.link(ob)

patterns = np.load(cfg["patterns"])
times = []
for k in range(patterns.shape[0]):
    rgba = np.ones((Hp, Wp, 4), dtype=np.float32)
    rgba[..., :3] = patterns[k][::-1, :, None]
    img.pixels.foreach_set(rgba.ravel()); img.update()
    sc.render.filepath = cfg["out"] + f"/{k:03d}.png"
    t0 = time.perf_counter(); bpy.ops.render.render(write_still=True); times.append(time.perf_counter() - t0)
json.dump({"times": times}, open(cfg["out"] + "/times.json", "w"))
'''


def blender_available(python: str | None = None) -> bool:
    """True when ``python -c 'import bpy'`` works."""
    try:
        r = subprocess.run([python or sys.executable, "-c", "import bpy"], capture_output=True, timeout=120)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return r.returncode == 0


def render_in_blender(system, meshes, patterns: np.ndarray, *, exposure: float, reference_distance_mm: float,
                      threads: int = 2, python: str | None = None, workdir=None, timeout: float = 600) -> dict:
    """Render ``patterns`` (K, H_p, W_p) in [0, 1] with Cycles in a subprocess.

    ``meshes``: list of ``(vertices_world (V,3) mm, faces (F,3), albedo, smooth)``.
    RETURNED VALUE: {"images": (K,H,W) float64 linear values in [0, 1] (16-bit PNG / 65535),
    "seconds_per_frame": list of Cycles render times, "wall_seconds": whole subprocess}.
    """
    import cv2

    tmp = Path(workdir or tempfile.mkdtemp(prefix="synth_blender_"))
    tmp.mkdir(parents=True, exist_ok=True)
    np.save(tmp / "patterns.npy", np.asarray(patterns, dtype=np.float32))
    power = 4 * math.pi ** 2 * exposure * (reference_distance_mm / 1000.0) ** 2
    cfg = {"camera": system.camera.to_dict(), "projector": system.projector.to_dict(), "power_w": power,
           "threads": int(threads), "patterns": str(tmp / "patterns.npy"), "out": str(tmp),
           "objects": [{"vertices": np.asarray(V).tolist(), "faces": np.asarray(F).tolist(), "albedo": float(a),
                        "smooth": bool(s)} for V, F, a, s in meshes]}
    (tmp / "config.json").write_text(json.dumps(cfg))
    (tmp / "scene.py").write_text(_SCRIPT)
    t0 = time.perf_counter()
    r = subprocess.run([python or sys.executable, str(tmp / "scene.py"), str(tmp / "config.json")],
                       capture_output=True, text=True, timeout=timeout)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise RuntimeError(f"Blender render failed (exit {r.returncode}):\n{r.stderr[-3000:]}")
    imgs = np.stack([cv2.imread(str(tmp / f"{k:03d}.png"), cv2.IMREAD_UNCHANGED).astype(np.float64) / 65535.0
                     for k in range(len(patterns))])
    times = json.loads((tmp / "times.json").read_text())["times"]
    return {"images": imgs, "seconds_per_frame": times, "wall_seconds": wall}
