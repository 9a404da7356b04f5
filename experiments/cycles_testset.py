"""A bias-dominated test set rendered by Blender Cycles (issue 21, item 3).

Scenes like real captures - a held-out mesh (nefertiti, cheburashka, suzanne: never in the
training export) a few cm before a matte wall and/or standing on a table, cast shadows, the real
working distance (~840 mm) - rendered by Cycles with diffuse interreflection (``bounces`` diffuse
bounces), 12 phase steps of vertical fringes at f = 1, 48 and 96 (MF pairs 1 -> 48, 1 -> 96), then
the twin's sensor model (Poisson-Gaussian noise, 8-bit quantisation) at high SNR, so that the
errors of the traditional decode come from the bias of the unit phase, not from noise. Written in
the dataset schema (``unwrap.dataset_schema``, ``kind = "twin"``: the geometric truth is stored as
the projector coordinate), so ``calib eval --test FILE`` scores it unchanged.

Camera: the default system made ideal (no skew/distortion: Blender cannot represent them), the
full 640x480 camera cropped to ``size`` around the scene centre, at its full focal length: the
fringe period in camera pixels is that of the training data (13.6 px at f = 96), which a 2x
*reduced* camera would halve.

Light transport is linear in the projected image, and Cycles renders every frame of one job with
the same sampling seed (same paths), so a phase-shift stack is a linear combination of three
renders: ``P_k = a_k U + b_k P_0 + c_k P_q`` (U the uniform grey 0.5, P_0 and P_q the steps 0 and
N/4 of the frequency; coefficients solved on the projector images, residual checked). A scene
therefore costs 1 + 2 x (frequencies) Cycles frames instead of 12 x (frequencies); the stacks
synthesised are what the 12 renders with one seed would give (checked in
tests/test_cycles_testset.py against a direct Cycles render of a step: equal at >= 98 % of the
pixels, the rest by a single sample's amount). The unit frequency's three frames are rendered with
several seeds and averaged (its phase error is amplified f times); two seeds measure Cycles' noise.

Ground truth: the twin's own ray cast of the same scene (same triangles, analytic planes for the
wall and the table) gives the projector coordinate per camera pixel; it is checked against
Cycles' geometry: Cycles' direct-light render (0 bounces, 1 sample, point-sampled pixel centres)
must be lit exactly where the twin is, and traditional MF on Cycles' noise-free direct frames
must give the twin's orders (``label_check``'s "clean" columns, as in the export).

Frames: world mm, y up in the image, z towards the camera (the camera sits at ~(109, -93, 836)).
A scene is built in a *room* frame (x right, y up, z towards the viewer; table y = ``table_y``,
wall z = ``wall_z``) and tilted by ``TILT_DEG`` about x, so that the camera looks down on the
table at ~23 degrees as a real bench camera does.
"""
from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import ExperimentError
from .gi_bias import _phase, _rect, _rot_y, cached_cycles, wrap

#: The held-out meshes (synth/data/export_test.toml).
MESH_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "meshes"
FREQUENCIES = (1.0, 48.0, 96.0)
STEPS = 12
TILT_DEG = 30.0
EXPOSURE = 0.8
#: High SNR: full well 20000 e- and 5 e- read noise at 8 bits (the twin test set: 2300 e-).
FULL_WELL_E = 20000.0
READ_NOISE_E = 5.0
BITS = 8
MIN_MODULATION = 0.02


@dataclass
class CyclesScene:
    """One scene for both renderers: ``objects`` (the twin's ray cast) and ``meshes``
    ((V world mm, F, albedo, smooth) for Cycles), and a description."""

    name: str
    objects: list
    meshes: list
    note: str
    params: dict = field(default_factory=dict)


def rot_x(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])


#: File frame -> room frame (x right, y up, face towards +z) of each held-out mesh.
MESH_FRAMES = {
    "nefertiti": np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], float),   # z up, face -y
    "cheburashka": np.eye(3),                                          # y up, face +z
    "suzanne": np.eye(3),                                              # y up, face +z
}


def placed_mesh(name: str, height_mm: float, yaw_deg: float, bottom_y: float, back_z: float, x: float = 0.0,
                mesh_dir=None):
    """Mesh ``name`` in the room frame: ``height_mm`` tall (room y), turned ``yaw_deg`` about y,
    its lowest point at y = ``bottom_y``, its rearmost at z = ``back_z``, centred on x = ``x``."""
    from synth.scenes.meshes import load_mesh

    path = Path(mesh_dir or MESH_DIR) / f"{name}.obj"
    if not path.is_file():
        raise ExperimentError(f"{path}: mesh not found (the held-out meshes live in ../shared/data/meshes)")
    V, F = load_mesh(path)
    V = np.asarray(V, np.float64) @ MESH_FRAMES[name].T
    V = (V - (V.max(0) + V.min(0)) / 2) * (height_mm / float(V[:, 1].max() - V[:, 1].min()))
    V = V @ _rot_y(yaw_deg).T
    V += np.array([x - (V[:, 0].max() + V[:, 0].min()) / 2, bottom_y - V[:, 1].min(), back_z - V[:, 2].min()])
    return V, np.asarray(F)


#: The scenes: mesh, height (mm), yaw (deg), gap before the wall (mm, None: no wall), table
#: (True: standing on it; False: hanging before the wall), albedos (object, wall, table).
SCENES = {
    "nefertiti-corner": dict(mesh="nefertiti", height=70.0, yaw=25.0, gap=12.0, table=True,
                             albedo=(0.85, 0.8, 0.7), x=0.0),
    "cheburashka-table": dict(mesh="cheburashka", height=60.0, yaw=-20.0, gap=35.0, table=True,
                              albedo=(0.8, 0.85, 0.6), x=0.0),
    "suzanne-wall": dict(mesh="suzanne", height=45.0, yaw=-15.0, gap=6.0, table=False,
                         albedo=(0.85, 0.8, 0.7), x=0.0),
    "suzanne-table": dict(mesh="suzanne", height=38.0, yaw=30.0, gap=20.0, table=True,
                          albedo=(0.75, 0.85, 0.7), x=0.0),
}
TABLE_Y = -32.0


def build_scene(name: str, *, mesh_dir=None) -> CyclesScene:
    """Scene ``name`` of :data:`SCENES` in the world frame (module docstring)."""
    from synth.scenes.objects import Mesh, Plane

    if name not in SCENES:
        raise ExperimentError(f"unknown Cycles test scene {name!r}; expected one of {sorted(SCENES)}")
    d = SCENES[name]
    a_obj, a_wall, a_table = d["albedo"]
    bottom = TABLE_Y if d["table"] else -d["height"] / 2
    # the mesh's rear at z = -gap, the wall behind it at z = -gap - (object depth) ... simpler: the
    # object's rear is `gap` in front of the wall at z = wall_z
    wall_z = -30.0
    V, F = placed_mesh(d["mesh"], d["height"], d["yaw"], bottom, wall_z + d["gap"], d["x"], mesh_dir)
    T = rot_x(TILT_DEG)  # room -> world: the room's up leans towards the camera (+z)
    objects, meshes = [], []
    Vw = V @ T.T
    objects.append(Mesh(d["mesh"], np.eye(3), [0, 0, 0], Vw, F, a_obj, True))
    meshes.append((Vw, F, a_obj, True))
    wall_size = (400.0, 300.0)
    wall_c = np.array([0.0, TABLE_Y + wall_size[1] / 2 if d["table"] else 0.0, wall_z])
    R_wall = T  # plane z = 0 of the object frame, normal +z (room) -> towards the viewer
    objects.append(Plane("wall", R_wall, T @ wall_c, a_wall, wall_size))
    Vr, Fr = _rect(wall_c, np.eye(3), wall_size, 4)
    meshes.append((Vr @ T.T, Fr, a_wall, False))
    if d["table"]:
        table_size = (400.0, 300.0)  # x by z
        R_tab = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], float)  # object z -> room +y (up)
        tab_c = np.array([0.0, TABLE_Y, wall_z + table_size[1] / 2])
        objects.append(Plane("table", T @ R_tab, T @ tab_c, a_table, table_size))
        Vt, Ft = _rect(tab_c, R_tab, table_size, 4)
        meshes.append((Vt @ T.T, Ft, a_table, False))
    note = (f"{d['mesh']} {d['height']:g} mm tall, yaw {d['yaw']:g} deg, {d['gap']:g} mm before a wall"
            + (", standing on a table" if d["table"] else "") + f"; albedo {a_obj}/{a_wall}"
            + (f"/{a_table}" if d["table"] else ""))
    return CyclesScene(name, objects, meshes, note, {"scene": name, **{k: v for k, v in d.items()},
                                                      "tilt_deg": TILT_DEG, "table_y": TABLE_Y, "wall_z": wall_z})


def testset_system(size=(320, 240)):
    """The default system made ideal, its camera cropped to ``size`` (W, H) around the image of
    the world origin at the full focal length (pixel centres at integer coordinates)."""
    from calib import default_system
    from calib.system import SystemModel

    s = default_system().ideal()
    cam = s.camera
    W, H = int(size[0]), int(size[1])
    if W > cam.width or H > cam.height or W < 8 or H < 8:
        raise ExperimentError(f"camera size {W}x{H}: expected within 8x8 .. {cam.width}x{cam.height} (a crop)")
    q0 = cam.project(np.zeros((1, 3)))[0]
    x0 = int(np.clip(round(q0[0] - W / 2), 0, cam.width - W))
    y0 = int(np.clip(round(q0[1] - H / 2), 0, cam.height - H))
    K = np.array(cam.K, dtype=np.float64)
    K[0, 2] -= x0
    K[1, 2] -= y0
    K[1, 1] = K[0, 0]  # Blender's pixels are square
    return SystemModel(cam.with_(size=(W, H), K=K), s.projector, {**dict(s.meta), "crop": [x0, y0, W, H]})


def patterns_and_basis(system, frequencies=FREQUENCIES, steps: int = STEPS):
    """(patterns, basis images (B, H_p, W_p) float32 in [0, 1], coefficients (K, B)): the K
    pattern images are ``coefficients @ basis`` (module docstring); refused unless exact to 1e-5."""
    from synth.scenes.sequence import phase_sequence

    if steps % 4:
        raise ExperimentError(f"steps {steps}: the basis uses the step N/4 (a quarter period): give a multiple of 4")
    patterns = phase_sequence(("v",), tuple(frequencies), steps)
    size = system.projector.size
    imgs = np.stack([p.projector_image(size, 0.5, 0.5) for p in patterns]).astype(np.float64)
    basis = [np.full(imgs.shape[1:], 0.5)]
    for j in range(len(frequencies)):
        basis += [imgs[j * steps], imgs[j * steps + steps // 4]]
    Bm = np.stack(basis).reshape(len(basis), -1)
    coef = np.zeros((len(patterns), len(basis)))
    for j in range(len(frequencies)):
        cols = [0, 1 + 2 * j, 2 + 2 * j]
        X = Bm[cols].T
        for k in range(steps):
            y = imgs[j * steps + k].ravel()
            c, *_ = np.linalg.lstsq(X[::61], y[::61], rcond=None)   # a subset fixes c; all pixels check it
            if np.abs(X @ c - y).max() > 1e-5:
                raise ExperimentError("a phase-shift step is not a combination of the basis images "
                                      "(pattern convention?)")
            coef[j * steps + k, cols] = c
    return patterns, np.stack(basis).astype(np.float32), coef


def _cache_key(scene_name: str, system, **kw) -> str:
    """The frame cache's file name: the scene's definition, the tilt, the whole system (camera and
    projector: intrinsics, pose, sizes), the exposure and the render settings ``kw``."""
    from calib.io.calibration_json import system_to_dict

    h = hashlib.sha1(json.dumps({"scene": SCENES[scene_name] if scene_name in SCENES else scene_name,
                                 "tilt": TILT_DEG, "system": system_to_dict(system), "exposure": EXPOSURE, **kw},
                                sort_keys=True, default=str).encode())
    return f"{scene_name}_{h.hexdigest()[:10]}.npz"


def cycles_frames(scene: CyclesScene, system, basis: np.ndarray, *, samples: int, bounces: int, seed: int = 0,
                  threads: int = 2, cache_dir=None, timeout: float = 7200) -> dict:
    """Cycles' (B, H, W) float64 linear images of ``basis`` on ``scene`` and its seconds per
    frame; cached as .npz in ``cache_dir`` (None: no cache), keyed by scene, camera and settings."""
    from synth.blender_twin import render_in_blender

    d_ref = float(np.linalg.norm(system.projector.center_world))
    path = None
    if cache_dir is not None:
        key = _cache_key(scene.name, system, samples=samples, bounces=bounces, seed=seed, n=len(basis),
                         b=hashlib.sha1(np.ascontiguousarray(basis).tobytes()).hexdigest()[:8])
        path = Path(cache_dir) / "frames" / key
    return cached_cycles(path, lambda: render_in_blender(
        system, scene.meshes, basis, exposure=EXPOSURE, reference_distance_mm=d_ref, threads=threads,
        samples=samples, bounces=bounces, seed=seed, timeout=timeout))


def twin_geometry(scene: CyclesScene, system, patterns):
    """The twin's ray cast of the scene (synth.renderer.geometry.Geometry)."""
    from synth.effects.spec import Effects
    from synth.renderer.geometry import compute_geometry
    from synth.renderer.plan_log import PlanLog
    from synth.scenes.scene import Scene

    d_ref = float(np.linalg.norm(system.projector.center_world))
    eff = Effects(exposure=EXPOSURE, reference_distance_mm=d_ref, fringe_sampling="bilinear")
    return compute_geometry(Scene(system, scene.objects, patterns, eff), log=PlanLog())


def sensor(linear: np.ndarray, *, full_well_e: float = FULL_WELL_E, read_noise_e: float = READ_NOISE_E,
           bits: int = BITS, seed: int = 0) -> np.ndarray:
    """The twin's sensor model (synth.effects.sensor: Poisson-Gaussian noise in electrons, then
    clipping and quantisation) on linear images (K, H, W) -> counts (K, H, W) float64."""
    import torch

    from synth.effects.sensor import add_noise, quantise
    from synth.effects.spec import Noise

    t = torch.from_numpy(np.ascontiguousarray(linear, dtype=np.float32)).clone()
    gen = torch.Generator().manual_seed(int(seed))
    t = add_noise(t, Noise(full_well_e, read_noise_e, int(seed)), gen)
    return quantise(t, bits).numpy().astype(np.float64)


def unit_phase(stack: np.ndarray) -> np.ndarray:
    """The wrapped phase (H, W) rad of an N-step stack (K, H, W) (experiments.gi_bias's)."""
    return _phase(stack)[0]


def cycles_stacks(scene: CyclesScene, system, coef, basis, *, samples: int, bounces: int, threads: int, cache_dir,
                  unit_seeds=(0, 1), steps: int = STEPS) -> dict:
    """Cycles' phase-shift stacks (K, H, W) with interreflection (``gi``; the unit frequency's
    basis averaged over ``unit_seeds``) and with direct light only (``direct``, 1 sample), the
    unit stack of each of the first two seeds (``unit_by_seed``) and the GI seconds per frame."""
    gi = cycles_frames(scene, system, basis, samples=samples, bounces=bounces, seed=unit_seeds[0], threads=threads,
                       cache_dir=cache_dir)
    direct = cycles_frames(scene, system, basis, samples=1, bounces=0, seed=0, threads=threads, cache_dir=cache_dir)
    stack_gi = np.einsum("kb,bhw->khw", coef, gi["images"])
    unit = [gi["images"][:3]] + [cycles_frames(scene, system, basis[:3], samples=samples, bounces=bounces, seed=s,
                                               threads=threads, cache_dir=cache_dir)["images"] for s in unit_seeds[1:]]
    stack_gi[:steps] = np.einsum("kb,bhw->khw", coef[:steps, :3], np.mean(unit, axis=0))
    return {"gi": stack_gi, "direct": np.einsum("kb,bhw->khw", coef, direct["images"]),
            "direct_uniform": direct["images"][0], "seeds": len(unit),
            "unit_by_seed": [np.einsum("kb,bhw->khw", coef[:steps, :3], u) for u in unit[:2]],
            "seconds_per_frame": float(np.mean(gi["seconds_per_frame"]))}


def phase_arrays(counts: np.ndarray, frequencies, steps: int) -> dict:
    """The ``v/phase``, ``v/modulation``, ``v/flags`` arrays (F, H, W) of quantised stacks, as the
    export computes them (synth.export.sample)."""
    from unwrap.dataset_schema import (FLAG_LOW_MODULATION, FLAG_OUT_OF_RANGE, FLAG_SATURATED, encode_modulation,
                                       encode_phase)
    from unwrap.phase_shift import wrapped_phase

    top = float((1 << BITS) - 1)
    F, H, W = len(frequencies), counts.shape[1], counts.shape[2]
    ph, mod, flags = np.zeros((F, H, W), np.int16), np.zeros((F, H, W), np.uint16), np.zeros((F, H, W), np.uint8)
    for j in range(F):
        w = wrapped_phase(counts[j * steps:(j + 1) * steps], min_modulation=MIN_MODULATION * top, saturation=top)
        ph[j] = encode_phase(np.where(w.valid, w.phase, 0.0))
        mod[j] = encode_modulation(w.B / top)
        flags[j] = (w.low_modulation * FLAG_LOW_MODULATION | w.saturated * FLAG_SATURATED
                    | w.out_of_range * FLAG_OUT_OF_RANGE).astype(np.uint8)
    return {"v/phase": ph, "v/modulation": mod, "v/flags": flags}


def label_check(phases: dict, orders: np.ndarray, frequencies, width: float, lit, edge) -> np.ndarray:
    """(F, 2) mismatches (interior, edge) of traditional MF 1 -> f on ``phases`` ({f: (H, W)})
    against the geometric ``orders`` (F, H, W); row 0 (the unit) -1."""
    from unwrap.temporal import mf_unwrap

    out = np.full((len(frequencies), 2), -1, np.int32)
    for j, f in enumerate(frequencies[1:], start=1):
        r = mf_unwrap([phases[frequencies[0]], phases[f]], (frequencies[0], f), width=width, valid=lit)
        wrong = lit & (np.asarray(r.order) != orders[j])
        out[j] = [int((wrong & ~edge).sum()), int((wrong & edge).sum())]
    return out


def noise_dependence(p0, p1, p_mean, n_seeds: int, phases: dict, orders: np.ndarray, frequencies, width: float,
                     mask) -> dict:
    """How much of the traditional error Cycles' noise makes: {f: [error with the unit phase of
    seed 0, of seed 1, of the mean of ``n_seeds`` seeds (1/n the noise variance), extrapolated to
    no Cycles noise]} (fractions of ``mask``; MF 1 -> f on the noise-free stacks, high phase
    ``phases[f]``, against the true order relative to it). The extrapolation assumes the error
    grows linearly with the noise variance: e(0) = e(var / n) - (e(var) - e(var / n)) / (n - 1)."""
    from unwrap.temporal import mf_unwrap

    out = {}
    for j, f in enumerate(frequencies[1:], start=1):
        rates = [float(np.mean((np.asarray(mf_unwrap([p, phases[f]], (frequencies[0], f), width=width,
                                                     valid=mask).order) != orders[j])[mask]))
                 for p in (p0, p1, p_mean)]
        e1 = (rates[0] + rates[1]) / 2
        out[f"{f:g}"] = rates + [rates[2] - (e1 - rates[2]) / (n_seeds - 1)]
    return out


def make_sample(scene: CyclesScene, system, *, samples: int, bounces: int = 4, threads: int = 2, cache_dir=None,
                noise_seed: int = 0, unit_seeds=(0, 1), frequencies=FREQUENCIES, steps: int = STEPS,
                full_well_e: float = FULL_WELL_E, read_noise_e: float = READ_NOISE_E) -> dict:
    """Render ``scene`` with Cycles and reduce it to one dataset sample (unwrap.dataset_schema):
    {"arrays", "params", "label_check" (1, F, 4), "stats"}. ``unit_seeds``: the unit frequency's
    basis frames are rendered with each of these seeds and averaged (its phase error is amplified
    f times, so it gets the samples); the first two measure Cycles' own noise per seed."""
    from unwrap.dataset_schema import MASK_EDGE, MASK_LIT, MASK_SHADOW, MASK_SURFACE
    from synth.export.sample import edge_mask
    from synth.renderer.truth import phase_truth

    t0 = time.perf_counter()
    patterns, basis, coef = patterns_and_basis(system, frequencies, steps)
    W, H = system.camera.size
    geom = twin_geometry(scene, system, patterns)
    st = cycles_stacks(scene, system, coef, basis, samples=samples, bounces=bounces, threads=threads,
                       cache_dir=cache_dir, unit_seeds=unit_seeds, steps=steps)
    lit = geom.lit.reshape(H, W).numpy()
    edge = edge_mask(geom)
    agree_interior = float(np.mean(((st["direct_uniform"] > 1e-4) == lit)[~edge]))  # Cycles lit where the twin is
    counts = sensor(st["gi"], full_well_e=full_well_e, read_noise_e=read_noise_e, seed=noise_seed)
    arrays = phase_arrays(counts, frequencies, steps)
    truth = [phase_truth(geom, system.projector.size, "v", f) for f in frequencies]   # (Phi, order) per f
    orders = np.stack([t[1] for t in truth]).astype(np.int8)
    sl = {f: slice(j * steps, (j + 1) * steps) for j, f in enumerate(frequencies)}
    clean = {f: unit_phase(st["direct"][sl[f]]) for f in frequencies}
    biased = {f: unit_phase(st["gi"][sl[f]]) for f in frequencies}
    Wp = system.projector.width
    check = np.concatenate([label_check(clean, orders, frequencies, Wp, lit, edge),
                            label_check(biased, orders, frequencies, Wp, lit, edge)], axis=1)[None]
    masks = (geom.hit.reshape(H, W).numpy() * MASK_SURFACE | lit * MASK_LIT
             | geom.shadow.reshape(H, W).numpy() * MASK_SHADOW | edge * MASK_EDGE).astype(np.uint8)
    arrays.update({"masks": masks, "v/order": orders,
                   "v/coordinate": np.where(lit, geom.u_p.reshape(H, W).numpy(), np.nan).astype(np.float32)})
    # bias statistics: Cycles with interreflection against Cycles direct, unit frequency
    stats = {"lit_agreement_interior": agree_interior, "mask_for_bias": lit & ~edge,
             "bias_unit": wrap(biased[frequencies[0]] - clean[frequencies[0]])}
    if st["seeds"] > 1:
        s0, s1 = st["unit_by_seed"]
        p0, p1 = unit_phase(s0), unit_phase(s1)
        stats["noise_unit_per_seed"] = wrap(p1 - p0) / math.sqrt(2)
        stats["unit_seeds"] = st["seeds"]
        # true order relative to the noise-free high phase (a pixel at the +-pi cut counts right)
        rel = np.stack([np.rint((np.nan_to_num(t[0]) - biased[f]) / (2 * np.pi)) for t, f in zip(truth, frequencies)])
        stats["error_vs_cycles_noise"] = noise_dependence(p0, p1, biased[frequencies[0]], st["seeds"], biased, rel,
                                                          frequencies, Wp, lit & ~edge)
    params = {"renderer": "blender cycles", "scene": scene.params, "note": scene.note, "samples": samples,
              "bounces": bounces, "exposure": EXPOSURE, "unit_seeds": st["seeds"],
              "noise": {"full_well_e": full_well_e, "read_noise_e": read_noise_e, "bits": BITS, "seed": noise_seed},
              "camera_crop": system.meta.get("crop"), "basis_frames": len(basis),
              "cycles_seconds_per_frame": st["seconds_per_frame"], "lit_agreement_interior": agree_interior,
              "bias": bias_summary(stats, frequencies),
              "label_check_clean": {f"{f:g}": check[0, j, :2].tolist() for j, f in enumerate(frequencies) if j},
              "label_check_effects": {f"{f:g}": check[0, j, 2:].tolist() for j, f in enumerate(frequencies) if j},
              "seconds": time.perf_counter() - t0}
    return {"arrays": arrays, "params": params, "label_check": check, "stats": stats}


def bias_summary(stats: dict, frequencies=FREQUENCIES) -> dict:
    """Bias statistics of one sample: unit-phase bias RMS / p99 (rad and in fringes of each f),
    Cycles' noise RMS per seed, over lit non-edge pixels."""
    m = stats["mask_for_bias"]
    b = stats["bias_unit"][m]
    out = {"pixels": int(m.sum()), "bias_rms_rad": float(np.sqrt(np.mean(b ** 2))),
           "bias_p99_rad": float(np.percentile(np.abs(b), 99)),
           "lit_agreement_interior": stats["lit_agreement_interior"]}
    if "noise_unit_per_seed" in stats:
        n = stats["noise_unit_per_seed"][m]
        out["cycles_noise_rms_rad"] = float(np.sqrt(np.mean(n ** 2)))
        out["cycles_noise_median_abs_rad"] = float(np.median(np.abs(n)))
        out["unit_seeds"] = stats["unit_seeds"]
        # the unit phase of the file averages the seeds' frames: its noise is the per-seed one / sqrt(n)
        out["unit_noise_rms_rad"] = out["cycles_noise_rms_rad"] / math.sqrt(stats["unit_seeds"])
        out["error_vs_cycles_noise"] = stats["error_vs_cycles_noise"]
    for f in frequencies[1:]:
        out[f"bias_over_half_fringe_{f:g}"] = float(np.mean(np.abs(b) > math.pi / f))
    return out


def build_testset(out, *, scenes=tuple(SCENES), size=(320, 240), samples: int = 128, bounces: int = 4,
                  threads: int = 2, cache_dir=None, unit_seeds=(0, 1, 2, 3), progress=None) -> dict:
    """Render ``scenes`` and write the test file ``out`` (HDF5, one sample per scene, atomic,
    resumable through the frame cache in ``cache_dir``). Returns {"file", "scenes": [bias summary
    per scene], "seconds"}."""
    from synth.export.dataset import code_version
    from synth.export.writer import ShardWriter, fingerprint_of
    from unwrap.dataset_schema import SCHEMA, SCHEMA_VERSION
    from calib.io.calibration_json import system_to_dict

    system = testset_system(size)
    t0 = time.perf_counter()
    settings = {"scenes": list(scenes), "size": list(size), "samples": samples, "bounces": bounces,
                "frequencies": list(FREQUENCIES), "steps": STEPS, "full_well_e": FULL_WELL_E,
                "read_noise_e": READ_NOISE_E, "bits": BITS, "tilt_deg": TILT_DEG, "unit_seeds": list(unit_seeds)}
    sys_json = json.dumps(system_to_dict(system))
    cfg_json = json.dumps(settings, sort_keys=True)
    attrs = {"schema": SCHEMA, "schema_version": SCHEMA_VERSION, "kind": "twin", "orientations": ["v"],
             "frequencies": list(FREQUENCIES), "steps": [STEPS] * len(FREQUENCIES),
             "widths": json.dumps({"v": system.projector.width, "h": system.projector.height}),
             "camera_size": list(system.camera.size), "bits": BITS, "min_modulation": MIN_MODULATION,
             "system": sys_json, "config": "Cycles test set (experiments.cycles_testset): " + cfg_json,
             "config_json": cfg_json, "seed": 0, "code_version": code_version(), "codec": "gzip-1",
             "samples_total": len(scenes), "shard": [0, 1], "units": "mm, px, rad", "renderer": "blender cycles",
             "fingerprint": fingerprint_of(cfg_json, sys_json, SCHEMA_VERSION)}
    groups = {"v": {"frequencies": list(FREQUENCIES), "steps": [STEPS] * len(FREQUENCIES)}}
    writer = ShardWriter(Path(out), range(len(scenes)), attrs, "gzip-1", attrs["fingerprint"], groups)
    summaries = []
    if not writer.complete():
        todo = set(writer.prepare())
        for i, name in enumerate(scenes):
            sc = build_scene(name)
            s = make_sample(sc, system, samples=samples, bounces=bounces, threads=threads, cache_dir=cache_dir,
                            noise_seed=i, unit_seeds=unit_seeds)
            summaries.append({"scene": name, "note": sc.note, **s["params"]["bias"],
                              "cycles_seconds_per_frame": s["params"]["cycles_seconds_per_frame"]})
            if i in todo:
                writer.write_part(i, s["arrays"], json.dumps(s["params"], default=str), s["label_check"])
            if progress:
                progress(name, summaries[-1])
        writer.assemble()
    return {"file": str(out), "scenes": summaries, "system": system, "seconds": time.perf_counter() - t0}


def wrong_pixel_context(wrong: np.ndarray, counted: np.ndarray, *, radius: int = 25, patch_px: int = 100) -> dict:
    """Where wrong orders sit (issue 21's bust analysis): counts of the ``wrong`` (H, W) pixels
    among ``counted`` ones, of those within ``radius`` px (Euclidean) of a pixel that is not
    counted (shadow, background, invalid), of the counted pixels there, and of the wrong pixels in
    8-connected patches of >= ``patch_px`` wrong pixels."""
    import cv2

    wrong = np.asarray(wrong, bool) & np.asarray(counted, bool)
    counted = np.asarray(counted, bool)
    dist = cv2.distanceTransform(counted.astype(np.uint8), cv2.DIST_L2, 5)  # distance to the nearest uncounted px
    near = counted & (dist <= radius)
    n, lab, st, _ = cv2.connectedComponentsWithStats(wrong.astype(np.uint8), connectivity=8)
    big = np.zeros(n, bool)
    big[1:] = st[1:, cv2.CC_STAT_AREA] >= patch_px
    return {"wrong": int(wrong.sum()), "wrong_near": int((wrong & near).sum()), "counted": int(counted.sum()),
            "counted_near": int(near.sum()), "wrong_in_patches": int(big[lab][wrong].sum())}
