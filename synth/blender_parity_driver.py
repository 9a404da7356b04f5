"""Runs inside a Python that has bpy (never imported by the toolkit): builds the twin with the
exported scene script of ``twin_mapping`` (camera, projector spot light with the pattern image,
Cycles render settings), adds only what parity needs, and renders every pattern.

Usage: python blender_parity_driver.py SCENE.py CONFIG.json

CONFIG.json: ``power_w``, ``threads``, ``samples``, ``projector_size`` [W, H], ``patterns`` (a
.npy (K, H_p, W_p) float32 in [0, 1], rows top-down), ``out`` (folder), ``objects`` (list of
``{"vertices": mm (V,3) world, "faces": (F,3), "albedo", "smooth"}``), ``camera_dof`` (null or
``{"focus_mm", "aperture_mm"}``: thin-lens depth of field with a circular aperture of that
diameter, focused at that camera depth), ``bounces`` (optional: light bounces beyond the direct
light) and per object ``subsurface`` (optional ``{"weight", "radius_mm", "method"}``: the
Principled BSDF's subsurface scattering, white radius). Writes ``OUT/NNN.png`` (16-bit grey, linear) and
``OUT/times.json`` (Cycles seconds per frame).
"""
import json
import sys
import time

import numpy as np

scene_script, config_path = sys.argv[1:3]
twin_scene = {"__name__": "twin_scene"}  # not "__main__": define the builder, build nothing yet
exec(compile(open(scene_script).read(), scene_script, "exec"), twin_scene)

import bpy  # noqa: E402

cfg = json.load(open(config_path))
Wp, Hp = cfg["projector_size"]
made = twin_scene["build_twin_scene"](twin_scene["TWIN"], pattern=(Wp, Hp), projector_power_w=cfg["power_w"])
pattern = next(n for n in made["projector_light"].data.node_tree.nodes if n.type == "TEX_IMAGE").image
twin_scene["configure_render"](samples=cfg["samples"], threads=cfg["threads"])
scene = bpy.context.scene
scene.render.image_settings.file_format = "PNG"
scene.render.image_settings.color_mode = "BW"
scene.render.image_settings.color_depth = "16"

if cfg.get("bounces"):  # light paths beyond direct light (subsurface scattering needs them)
    scene.cycles.max_bounces = cfg["bounces"]
    scene.cycles.diffuse_bounces = cfg["bounces"]
    scene.cycles.glossy_bounces = 0
    scene.cycles.transmission_bounces = 0
    scene.cycles.volume_bounces = 0
    scene.cycles.transparent_max_bounces = 0

dof = cfg.get("camera_dof")
if dof:
    cam = made["camera"].data
    cam.dof.use_dof = True
    cam.dof.focus_distance = dof["focus_mm"] / 1000.0
    # Cycles' aperture radius is lens / (2 f-stop) in scene units: a disc of aperture_mm diameter
    cam.dof.aperture_fstop = cam.lens / dof["aperture_mm"]
    cam.dof.aperture_blades = 0
    cam.dof.aperture_ratio = 1.0

for i, o in enumerate(cfg["objects"]):
    mesh = bpy.data.meshes.new(f"surface{i}")
    mesh.from_pydata((np.asarray(o["vertices"]) / 1000.0).tolist(), [], o["faces"])
    mesh.update()
    if o["smooth"]:
        for poly in mesh.polygons:
            poly.use_smooth = True
    mat = bpy.data.materials.new(f"lambert{i}")  # Lambertian: rough, no specular
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (o["albedo"],) * 3 + (1.0,)
    bsdf.inputs["Roughness"].default_value = 1.0
    bsdf.inputs["Specular IOR Level"].default_value = 0.0
    sss = o.get("subsurface")
    if sss:  # {"weight", "radius_mm", "method"}: Cycles' subsurface scattering (global illumination check)
        bsdf.subsurface_method = sss.get("method", "RANDOM_WALK")
        bsdf.inputs["Subsurface Weight"].default_value = sss["weight"]
        bsdf.inputs["Subsurface Radius"].default_value = (1.0, 1.0, 1.0)
        bsdf.inputs["Subsurface Scale"].default_value = sss["radius_mm"] / 1000.0
    mesh.materials.append(mat)
    scene.collection.objects.link(bpy.data.objects.new(f"surface{i}", mesh))

patterns = np.load(cfg["patterns"])
times = []
for k in range(patterns.shape[0]):
    rgba = np.ones((Hp, Wp, 4), dtype=np.float32)
    rgba[..., :3] = patterns[k][::-1, :, None]  # Blender's image rows run bottom-up
    pattern.pixels.foreach_set(rgba.ravel())
    pattern.update()
    scene.render.filepath = f"{cfg['out']}/{k:03d}.png"
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    times.append(time.perf_counter() - t0)
json.dump({"times": times}, open(f"{cfg['out']}/times.json", "w"))
