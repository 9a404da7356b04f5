"""Blender (bpy 4.5) scene builder for a twin: the body of the exported scene script.

This file is never imported by the toolkit (bpy is not a dependency): ``blender_export`` copies
it into a self-contained script, followed by the twin parameters. Run that script with Blender
(``blender --background --python scene.py``) or in a Python with the ``bpy`` module.

Facts used (BLENDER-NOTES.md, measured with bpy 4.5.15): the projector is a SPOT light with
``shadow_soft_size = 0`` and ``spot_blend = 0`` whose emission is an image texture looked up
through Texture Coordinate ``Normal`` -> (x/z, y/z) -> Mapping (POINT, scale (-fx/W, -fy/H, 1),
location ((cx + 0.5)/W, (H - cy - 0.5)/H, 0)) -> Image Texture (Non-Color, CLIP, Linear); scene
units metres with scale_length 1 (physical falloff); Cycles on the CPU, 1 sample, point-sampled
pixels (Blackman-Harris 0.01 px), no adaptive sampling, no denoising, 0 bounces, view transform
Raw, dither 0.
"""
import math

import bpy

MM = 0.001  # Blender scene units are metres


def _intrinsics(dev):
    """fx, fy, cx, cy (px) of the ideal pinhole the twin parameters describe."""
    w, h = dev["resolution"]
    fx = dev["focal_length_mm"] / dev["sensor_size_mm"][0] * w
    fy = fx * dev["pixel_aspect"][0] / dev["pixel_aspect"][1]
    cx = (w - 1) / 2.0 - dev["shift"][0] * w
    cy = (h - 1) / 2.0 + dev["shift"][1] * w * fy / fx
    return fx, fy, cx, cy


def _place(obj, dev):
    obj.location = [v * MM for v in dev["location_mm"]]
    obj.rotation_mode = "XYZ"
    obj.rotation_euler = [math.radians(a) for a in dev["rotation_euler_deg"]]


def add_camera(dev, name="Camera"):
    """A Blender camera object for one twin device (camera, or projector seen as a camera)."""
    data = bpy.data.cameras.new(name)
    data.type = "PERSP"
    data.lens_unit = "MILLIMETERS"
    data.sensor_fit = "HORIZONTAL"
    data.sensor_width = dev["sensor_size_mm"][0]
    data.sensor_height = dev["sensor_size_mm"][1]
    data.lens = dev["focal_length_mm"]
    data.shift_x, data.shift_y = dev["shift"]
    data.clip_start = 1.0 * MM
    data.clip_end = 100.0
    obj = bpy.data.objects.new(name, data)
    bpy.context.scene.collection.objects.link(obj)
    _place(obj, dev)
    return obj


def use_camera(obj, dev):
    """Make ``obj`` the scene camera with the device's resolution and pixel aspect."""
    scene = bpy.context.scene
    scene.camera = obj
    scene.render.resolution_x, scene.render.resolution_y = dev["resolution"]
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = dev["pixel_aspect"]


def add_projector_light(dev, pattern=None, power_w=1.0, name="Projector"):
    """The projector as a textured SPOT light; ``pattern`` is an image path, a bpy image, a size
    ``(W, H)`` (a blank float image for the caller to fill: ``light.data.node_tree`` holds it in its
    Image Texture node) or None."""
    w, h = dev["resolution"]
    fx, fy, cx, cy = _intrinsics(dev)
    light = bpy.data.lights.new(name, type="SPOT")
    light.energy = power_w
    light.shadow_soft_size = 0.0
    light.spot_blend = 0.0
    light.spot_size = math.radians(min(dev["spot"]["spot_size_deg"] * 1.02, 179.0))
    light.use_soft_falloff = False
    light.use_nodes = True
    nt = light.node_tree
    for node in list(nt.nodes):
        if node.type not in ("OUTPUT_LIGHT", "EMISSION"):
            nt.nodes.remove(node)
    emission = next(n for n in nt.nodes if n.type == "EMISSION")
    output = next(n for n in nt.nodes if n.type == "OUTPUT_LIGHT")
    coords = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    div_x = nt.nodes.new("ShaderNodeMath")
    div_x.operation = "DIVIDE"
    div_y = nt.nodes.new("ShaderNodeMath")
    div_y.operation = "DIVIDE"
    comb = nt.nodes.new("ShaderNodeCombineXYZ")
    mapping = nt.nodes.new("ShaderNodeMapping")
    mapping.vector_type = "POINT"
    mapping.inputs["Scale"].default_value = (-fx / w, -fy / h, 1.0)
    mapping.inputs["Location"].default_value = ((cx + 0.5) / w, (h - cy - 0.5) / h, 0.0)
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.extension = "CLIP"
    tex.interpolation = "Linear"
    if pattern is not None:
        if isinstance(pattern, str):
            image = bpy.data.images.load(pattern)
        elif isinstance(pattern, (tuple, list)):  # (W, H): a blank float image, filled by the caller
            image = bpy.data.images.new("pattern", int(pattern[0]), int(pattern[1]), float_buffer=True,
                                        is_data=True)
        else:
            image = pattern
        image.colorspace_settings.name = "Non-Color"
        tex.image = image
    links = nt.links
    links.new(coords.outputs["Normal"], sep.inputs["Vector"])
    links.new(sep.outputs["X"], div_x.inputs[0])
    links.new(sep.outputs["Z"], div_x.inputs[1])
    links.new(sep.outputs["Y"], div_y.inputs[0])
    links.new(sep.outputs["Z"], div_y.inputs[1])
    links.new(div_x.outputs[0], comb.inputs["X"])
    links.new(div_y.outputs[0], comb.inputs["Y"])
    links.new(comb.outputs["Vector"], mapping.inputs["Vector"])
    links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
    links.new(tex.outputs["Color"], emission.inputs["Color"])
    links.new(emission.outputs["Emission"], output.inputs["Surface"])
    obj = bpy.data.objects.new(name, light)
    bpy.context.scene.collection.objects.link(obj)
    _place(obj, dev)
    return obj


def configure_render(samples=1, threads=None):
    """Cycles on the CPU, deterministic point-sampled direct light, raw linear output."""
    scene = bpy.context.scene
    scene.unit_settings.system = "METRIC"
    scene.unit_settings.scale_length = 1.0
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.max_bounces = 0
    scene.cycles.pixel_filter_type = "BLACKMAN_HARRIS"
    scene.cycles.filter_width = 0.01
    scene.view_settings.view_transform = "Raw"
    scene.view_settings.look = "None"
    scene.render.dither_intensity = 0.0
    if threads:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = threads
    world = bpy.data.worlds.new("World") if scene.world is None else scene.world
    scene.world = world
    world.use_nodes = True
    bg = world.node_tree.nodes.get("Background")
    if bg is not None:
        bg.inputs["Strength"].default_value = 0.0


def build_twin_scene(twin, pattern=None, projector_power_w=1.0, reset=True):
    """Build the twin: camera (scene camera), projector camera, projector spot light.

    Returns a dict of the created objects.
    """
    if reset:
        bpy.ops.wm.read_factory_settings(use_empty=True)
    configure_render()
    cam = add_camera(twin["camera"], "Camera")
    prj_cam = add_camera(twin["projector"], "ProjectorCamera")
    light = add_projector_light(twin["projector"], pattern, projector_power_w, "Projector")
    use_camera(cam, twin["camera"])
    return {"camera": cam, "projector_camera": prj_cam, "projector_light": light}
