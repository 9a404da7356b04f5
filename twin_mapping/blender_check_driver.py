"""Run inside a Python that has bpy (never imported by the toolkit): build the exported twin scene,
then project points through Blender's own cameras.
Usage: python blender_check_driver.py SCENE.py POINTS.json OUT.json [SAVE.blend]

POINTS.json: {"camera": [[x, y, z], ...], "projector": [...]} in mm (world frame).
OUT.json: per device, Blender's read-back camera settings and the projected pixels (OpenCV
convention: pixel centres at integer coordinates, rows top-down) by two routes:
``matrices`` (matrix_world and calc_matrix_camera) and ``world_to_camera_view``.
"""
import json
import sys

scene_script, points_path, out_path = sys.argv[1:4]
save_blend = sys.argv[4] if len(sys.argv) > 4 else None
sys.argv = [scene_script]
namespace = {"__name__": "__main__"}
exec(compile(open(scene_script).read(), scene_script, "exec"), namespace)

import bpy  # noqa: E402
import numpy as np  # noqa: E402
from bpy_extras.object_utils import world_to_camera_view  # noqa: E402
from mathutils import Vector  # noqa: E402

twin = namespace["TWIN"]
points = json.load(open(points_path))
scene = bpy.context.scene
out = {}
for kind, obj_name in (("camera", "Camera"), ("projector", "ProjectorCamera")):
    obj = bpy.data.objects[obj_name]
    namespace["use_camera"](obj, twin[kind])
    depsgraph = bpy.context.evaluated_depsgraph_get()
    W, H = scene.render.resolution_x, scene.render.resolution_y
    ax, ay = scene.render.pixel_aspect_x, scene.render.pixel_aspect_y
    P = np.array(obj.calc_matrix_camera(depsgraph, x=W, y=H, scale_x=ax, scale_y=ay), dtype=np.float64)
    M = np.array(obj.matrix_world, dtype=np.float64)
    X = np.asarray(points[kind], dtype=np.float64) / 1000.0  # mm -> m
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
json.dump(out, open(out_path, "w"))
if save_blend:
    namespace["use_camera"](bpy.data.objects["Camera"], twin["camera"])
    bpy.ops.wm.save_as_mainfile(filepath=save_blend)
