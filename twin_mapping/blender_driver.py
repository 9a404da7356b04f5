"""Runs inside a Python that has bpy (never imported by the toolkit): builds the twin with the
exported scene script of ``twin_mapping`` (camera, projector camera, projector spot light, Cycles
render settings), then does one job. Started by :func:`twin_mapping.blender_run.run_in_blender`.

Usage: python blender_driver.py SCENE.py CONFIG.json

CONFIG.json ``job``:

- ``check``: ``points`` ({"camera": [[x, y, z], ...], "projector": [...]} in mm, world frame),
  ``out`` (JSON path), optional ``save_blend``. Writes, per device, Blender's read-back camera
  settings and the projected pixels (OpenCV convention: pixel centres at integer coordinates,
  rows top-down) by two routes: ``q_matrices`` (matrix_world and calc_matrix_camera) and
  ``q_world_to_camera_view``; and the projector light's settings.
- ``render``: ``power_w``, ``threads``, ``samples``, ``projector_size`` [W, H], ``patterns`` (a
  .npy (K, H_p, W_p) float32 in [0, 1], rows top-down), ``out`` (folder), ``objects`` (list of
  ``{"vertices": mm (V,3) world, "faces": (F,3), "albedo", "smooth"}``, optional ``subsurface``
  ``{"weight", "radius_mm", "method"}``: the Principled BSDF's subsurface scattering, white radius),
  ``bounces`` (optional: light bounces beyond the direct light), ``camera_dof`` (null or
  ``{"focus_mm", "aperture_mm"}``: thin-lens depth of field with a circular aperture of that
  diameter, focused at that camera depth), ``seed`` (optional: Cycles' sampling seed). Writes ``OUT/NNN.png`` (16-bit grey, linear) and
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


def check(cfg):
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    twin = twin_scene["TWIN"]
    twin_scene["build_twin_scene"](twin)
    scene = bpy.context.scene
    out = {}
    for kind, obj_name in (("camera", "Camera"), ("projector", "ProjectorCamera")):
        obj = bpy.data.objects[obj_name]
        twin_scene["use_camera"](obj, twin[kind])
        depsgraph = bpy.context.evaluated_depsgraph_get()
        W, H = scene.render.resolution_x, scene.render.resolution_y
        ax, ay = scene.render.pixel_aspect_x, scene.render.pixel_aspect_y
        P = np.array(obj.calc_matrix_camera(depsgraph, x=W, y=H, scale_x=ax, scale_y=ay), dtype=np.float64)
        M = np.array(obj.matrix_world, dtype=np.float64)
        X = np.asarray(cfg["points"][kind], dtype=np.float64) / 1000.0  # mm -> m
        Xh = np.concatenate([X, np.ones((len(X), 1))], axis=1)
        clip = (P @ np.linalg.inv(M) @ Xh.T).T
        ndc = clip[:, :2] / clip[:, 3:4]
        q_mat = np.stack([(ndc[:, 0] + 1) / 2 * W - 0.5, (1 - (ndc[:, 1] + 1) / 2) * H - 0.5], axis=1)
        q_w2c = []
        for p in X:
            c = world_to_camera_view(scene, obj, Vector(p))
            q_w2c.append([c.x * W - 0.5, (1 - c.y) * H - 0.5])
        out[kind] = {"matrix_world": M.tolist(), "lens": obj.data.lens, "sensor_width": obj.data.sensor_width,
                     "shift": [obj.data.shift_x, obj.data.shift_y], "resolution": [W, H],
                     "pixel_aspect": [ax, ay], "q_matrices": q_mat.tolist(), "q_world_to_camera_view": q_w2c}
    light = bpy.data.objects["Projector"]
    out["projector_light"] = {"matrix_world": np.array(light.matrix_world).tolist(), "type": light.data.type,
                              "spot_size": light.data.spot_size, "shadow_soft_size": light.data.shadow_soft_size}
    json.dump(out, open(cfg["out"], "w"))
    if cfg.get("save_blend"):
        twin_scene["use_camera"](bpy.data.objects["Camera"], twin["camera"])
        bpy.ops.wm.save_as_mainfile(filepath=cfg["save_blend"])


def render(cfg):
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
    if cfg.get("seed") is not None:  # Cycles' sampling pattern seed (two seeds measure its noise)
        scene.cycles.seed = int(cfg["seed"])
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
        if sss:  # Cycles' subsurface scattering (the global-illumination check)
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


{"check": check, "render": render}[cfg["job"]](cfg)
