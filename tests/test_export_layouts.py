"""Real-like scene layouts of the export (synth.export.layouts, issue 21 item 2): objects before a
wall at the drawn gap, on a table touching its top, the physically based interreflection drawn
and recorded per sample, reproducible from the seed, held-out meshes never drawn for training,
and a board alone still rendered without the effects."""
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from synth.export.config import ExportConfigError, config_from_dict, load_config
from synth.export.layouts import TABLE_WALL_CLEARANCE_MM, extent_along
from synth.export.scenes import draw_scene
from synth.export.dataset import base_system

from dataset_helpers import REPO

DATA = REPO / "synth" / "data"
HELD_OUT = {"nefertiti.obj", "cheburashka.obj", "suzanne.obj"}
REAL = ("export_real.toml", "export_real_fewstep.toml")


def _window_system(tmp_path, w=160, h=120):
    """The central w x h window of the built-in camera (same rays per pixel), as a calibration.json."""
    from calib.system import default_system
    from calib.io.calibration_json import system_to_dict

    d = system_to_dict(default_system())
    c = d["camera"]
    c["K"][0][2] -= (c["size"][0] - w) / 2
    c["K"][1][2] -= (c["size"][1] - h) / 2
    c["size"] = [w, h]
    path = tmp_path / "window.json"
    path.write_text(json.dumps(d))
    return str(path)


def _procedural(layouts, system_file="system_window320.json", **scene):
    """A real-like config without meshes (no shared data needed)."""
    d = load_config(DATA / "export_real.toml")
    sc = {"objects": [1, 3], "mesh_fraction": 0.0, "procedural": ["sphere", "blobs", "heightfield", "steps"],
          "size_mm": [30, 90], "layouts": layouts, **scene}
    eff = {"noise": {"full_well_e": [6000, 40000], "read_noise_e": [2, 10]},
           "global_illumination": {"subsurface": [0, 0.6], "scatter_mm": [0.5, 4]},
           "interreflection": {"chance": 1.0, "bounces": [1, 2], "patch_px": [32, 48]}}
    return config_from_dict({"export": {"samples": 4, "seed": 5}, "system": {"file": system_file},
                             "patterns": {"frequencies": [1, 8], "steps": 4, "orientations": ["v"]},
                             "scene": sc, "effects": eff}, base_dir=d.base_dir)


def _layout_draws(cfg, n=8):
    """(system, objects, extra objects by name (wall / table), params) of samples 0..n-1."""
    system, _ = base_system(cfg)
    for i in range(n):
        scene, params = draw_scene(cfg, system, np.random.default_rng([cfg.seed, i, 0]))
        objs = scene.objects
        yield (system, [o for o in objs if o.name.startswith("object")],
               {o.name: o for o in objs if not o.name.startswith("object")}, params)


def test_wall_layout_puts_every_object_at_its_drawn_gap_before_the_wall():
    for system, objects, extra, params in _layout_draws(_procedural(["wall"])):
        wall = extra["wall"]
        n, P = wall.R[:, 2].numpy(), wall.t.numpy()
        assert params["layout"]["kind"] == "wall" and n @ (system.camera.center_world - P) > 0  # faces the camera
        for obj, gap in zip(objects, params["layout"]["gaps_mm"]):
            nearest = float(n @ (obj.t.numpy() - P)) + extent_along(obj, n)
            assert nearest == pytest.approx(gap, abs=1e-6)
            assert 2.0 <= gap <= 60.0


def test_table_layout_stands_every_object_on_the_top():
    for system, objects, extra, params in _layout_draws(_procedural(["table"], table_wall=1.0)):
        table = extra["table"]
        n, A = table.R[:, 2].numpy(), table.t.numpy()
        # the camera's optical axis meets the top at the drawn elevation
        elev = np.degrees(np.arcsin(n @ -system.camera.R[2]))
        assert elev == pytest.approx(params["layout"]["elevation_deg"], abs=1e-9)
        assert 12.0 <= params["layout"]["elevation_deg"] <= 50.0
        assert n @ (system.camera.center_world - A) > 0 and "wall" in extra and "wall" in params["layout"]
        for obj in objects:
            assert float(n @ (obj.t.numpy() - A)) + extent_along(obj, n) == pytest.approx(0.0, abs=1e-6)
        # no object reaches into the wall behind the table
        wall = extra["wall"]
        nw, P = wall.R[:, 2].numpy(), wall.t.numpy()
        nw = nw if nw @ (system.camera.center_world - P) > 0 else -nw
        for obj in objects:
            assert float(nw @ (obj.t.numpy() - P)) + extent_along(obj, nw) >= TABLE_WALL_CLEARANCE_MM - 1e-6


def test_a_table_object_stands_on_the_true_ray_of_its_drawn_pixel():
    """The foot point of a table object lies on the camera model's own ray through the drawn
    pixel (skew and strong distortion here), so it projects back onto that pixel."""
    import math
    from dataclasses import replace

    from calib.system import default_system
    from synth.export.layouts import table_foot

    system = default_system()
    cam = system.camera
    K = np.array(cam.K)
    K[0, 1] = 4.0                                                   # skew, px
    cam = cam.with_(K=K, distortion=np.array([-4.0, 10.0, 2e-3, -1.5e-3, 0.0]))   # ~8 % at the corners
    system = replace(system, camera=cam)
    e = math.radians(25.0)
    n = cam.R.T @ np.array([0.0, -math.cos(e), -math.sin(e)])
    A = cam.R.T @ (np.array([0.0, 0.12 * 900.0, 900.0]) - cam.t)
    uv = np.stack(np.meshgrid(np.linspace(0.2, 0.8, 5) * cam.width, np.linspace(0.35, 0.9, 4) * cam.height),
                  -1).reshape(-1, 2)
    feet = np.array([table_foot(system, u, v, n, A) for u, v in uv])
    assert np.abs((feet - A) @ n).max() < 1e-6                      # on the table plane
    assert np.abs(cam.project(feet) - uv).max() < 1e-6              # where they were drawn
    # the pinhole ray would have put them tens of pixels off: the test sees a distortion-free ray
    pin = cam.without_skew_and_distortion()
    assert np.abs(pin.project(feet) - uv).max() > 5.0


def test_layout_parameters_and_effects_are_recorded_and_reproducible_from_the_seed():
    cfg = _procedural(["wall", "table"])
    system, _ = base_system(cfg)
    kinds = set()
    for i in range(6):
        a = draw_scene(cfg, system, np.random.default_rng([cfg.seed, i, 0]))[1]
        b = draw_scene(cfg, system, np.random.default_rng([cfg.seed, i, 0]))[1]
        assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
        kinds.add(a["layout"]["kind"])
        ir = a["effects"]["interreflection"]
        assert ir["bounces"] in (1, 2) and 32.0 <= ir["patch_px"] <= 48.0 and ir["mesh_visibility"]
        assert all(len(m) == 2 for m in a["effects"]["global_illumination"]["per_object"])
        assert a["effects"]["global_illumination"]["interreflection"] == 0   # the screen-space term stays off
    assert kinds == {"wall", "table"}
    other = draw_scene(cfg, system, np.random.default_rng([cfg.seed + 1, 0, 0]))[1]
    assert json.dumps(other, sort_keys=True) != json.dumps(a, sort_keys=True)


def test_free_layout_configs_keep_their_fingerprint_and_draws():
    """Configs without layouts serialise as before layouts existed (same fingerprint, so an export
    started before keeps resuming), and draw no extra random numbers."""
    cfg = load_config(DATA / "export_train.toml")
    d = cfg.to_dict()
    assert "layouts" not in d and "wall_gap_mm" not in d and "interreflection" not in d["effects"]
    assert "layouts" in load_config(DATA / "export_real.toml").to_dict()


def test_layout_and_interreflection_keys_are_validated_by_name():
    base = {"export": {"samples": 1}}
    for scene, msg in (({"layouts": ["wall", "kitchen"]}, "scene.layouts"), ({"layouts": []}, "scene.layouts"),
                       ({"table_wall": 1.5}, "scene.table_wall"), ({"wall_tilt_deg": [0, 85]}, "scene.wall_tilt_deg")):
        with pytest.raises(ExportConfigError, match=msg):
            config_from_dict({**base, "scene": scene})
    for eff, msg in (({"interreflection": {"bounces": [1, 2]}}, "effects.interreflection.chance: missing"),
                     ({"interreflection": {"chance": 1, "bounces": [1, 3]}}, "effects.interreflection.bounces"),
                     ({"interreflection": {"chance": 1, "speed": 2}}, "speed")):
        with pytest.raises(ExportConfigError, match=msg):
            config_from_dict({**base, "effects": eff})


@pytest.mark.realdata
def test_real_like_configs_never_draw_a_held_out_mesh():
    from tests.conftest import shared_data

    shared_data("meshes")
    for name in REAL:
        cfg = load_config(DATA / name)
        assert cfg.layouts == ("wall", "table") and cfg.meshes and not {Path(m).name for m in cfg.meshes} & HELD_OUT
        system, _ = base_system(cfg)
        drawn = set()
        for i in range(60):
            params = draw_scene(cfg, system, np.random.default_rng([cfg.seed, i, 0]))[1]
            drawn |= {o["file"] for o in params["objects"] if o["kind"] == "mesh"}
        assert drawn and not drawn & HELD_OUT, drawn


def test_the_new_scene_kinds_render_with_interreflection_and_clean_labels(tmp_path):
    from synth.export.sample import make_sample

    cfg = _procedural(["wall", "table"], _window_system(tmp_path), size_mm=[15, 40])
    system, _ = base_system(cfg)
    seen = set()
    for i in range(2):
        s = make_sample(cfg, system, i)
        plan = s.params["plan"]
        seen.add(s.params["layout"]["kind"])
        assert not any(line.startswith("interreflection: skipped") for line in plan), plan
        assert any(line.startswith("interreflection") for line in plan)
        assert s.label_check[..., :2].max() == 0             # clean render: labels exact
        masks = s.arrays["masks"]
        assert (masks & 1).mean() > 0.5                      # the wall / table fills the view
    assert seen == {"wall", "table"}


def test_a_board_alone_renders_without_the_drawn_effects():
    """The effects a real-like sample draws (interreflection, subsurface of its objects) leave a
    lone calibration board untouched: the renderer skips them and the images are bit-identical."""
    from dataclasses import replace

    from synth import Scene, render
    from synth.scenes.scene import scene_from_dict

    cfg = _procedural(["wall"])
    system, _ = base_system(cfg)
    params = {}
    from synth.export.scenes import draw_effects
    eff = draw_effects(cfg, system, 1, np.random.default_rng(3), params)
    assert eff.interreflection is not None
    board = scene_from_dict({"objects": [{"kind": "board", "board": {"kind": "circles", "rows": 9, "cols": 11,
                                                                      "spacing_mm": 20.0}}],
                             "patterns": {"sequence": [{"kind": "phase", "orientation": "v", "frequencies": [1, 8],
                                                        "steps": 4}]}})
    eff = replace(eff, noise=None, global_illumination=None, camera_defocus=None, projector_defocus=None)
    pat = board.patterns
    asked = render(Scene(system, board.objects, pat, eff, "board"))
    plain = render(Scene(system, board.objects, pat, replace(eff, interreflection=None), "board"))
    assert any(line.startswith("interreflection: skipped (a single convex board") for line in asked.plan)
    assert torch.equal(asked.images, plain.images)
