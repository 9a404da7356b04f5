"""Speed of the synth renderer at 640x480 (the paper's camera) against Blender Cycles in the
same run: ``python -m bench.synth_speed [--no-blender] [--threads 2] [--repeats 3] [--quick]``
(``--quick``: one repeat, plane and ball only, no Cycles).

Rows: the paper's 72-image stack (v/h, 12 steps, f = 1, 8, 48) on a plane, on the ball, on a
~100k-triangle mesh (bunny, 69k, on a blobs relief, 30k) with shadows + projector and camera
defocus + noise, and on the same mesh with exactly the effects of the 1-sample Cycles frame
(cast shadows, no defocus, no noise: matched fidelity). Every time is the minimum over
``--repeats`` runs (the machine may be shared). The compiled (numba) kernels are loaded from
numba's on-disk cache once per process; that one-time cost is timed first and reported apart.

On a machine where another job holds a core, run with ``OMP_WAIT_POLICY=PASSIVE``: torch's
OpenMP threads otherwise spin at every operation's barrier while their partner thread is
descheduled (measured in session 3: the plane's twin stack took 1.3 s of geometry with 2 threads
against 0.13-0.20 s with passive waiting or 1 thread). Cycles (TBB) is not affected by the variable.

- geometry, cold: the whole geometry stage with an empty camera-ray cache (a camera seen for
  the first time: includes inverting its lens distortion for every pixel);
- geometry, new pose: the same once the camera's rays are cached (every further scene pose or
  scene seen by that camera, e.g. the 9 poses of a calibration session);
- pattern stage images/s: the stack once geometry is done (quantisation included when it is
  fused with the patterns);
- whole stack: geometry (cold) + every stage, 72 images.

Each row is timed on the real system (lens distortion: rays by Newton inversion, distorted
projection) and on the twin system Blender renders (ideal, square pixels); the speed-up against
Cycles uses the latter: the same frame.

Cycles (same run): one 640x480 frame of the same scene (ideal twin: Blender cannot represent
distortion), the phase pattern v f=48 step 0, 1 sample, point-sampled pixels, direct light only,
CPU with ``--threads`` threads, time of ``bpy.ops.render.render`` (minimum over 2 frames in each
of the ``--repeats`` Blender runs, which alternate with ours). That is
the fidelity the parity test matches (plane and ball: <= 0.01 8-bit levels); the mesh row's
Cycles frame has no depth of field (converging it needs many samples) and no noise, so its
Cycles time is a lower bound and the speed-up an under-estimate; the same frame with Cycles' depth
of field (64 samples) is timed too. Last, the full-size parity (images and phase) of the plane and
the ball, Cycles against us, as in tests/test_synth_blender.py at 160x120.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch


DOF_SAMPLES = 64  # the Blender DOF reference check (tests/test_synth_reference.py) converges at 32 at 160x120


def _scenes(quick: bool = False):
    from calib import default_system
    from synth import Mesh, Plane, Scene, Sphere, blobs_heights, heightfield_mesh, load_mesh, phase_sequence
    from synth.effects.spec import Defocus, Effects, Noise

    system = default_system()
    seq = phase_sequence(("v", "h"), (1, 8, 48), 12)
    yield "plane", Scene(system, [Plane("plane", np.eye(3), [0, 0, 0])], seq)
    yield "ball", Scene(system, [Sphere("ball", np.eye(3), [0, 0, 0])], seq)
    if quick:
        return
    mesh_path = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "meshes" / "stanford-bunny.obj"
    objs = []
    if mesh_path.exists():
        V, F = load_mesh(mesh_path)
        V = (V - (V.min(0) + V.max(0)) / 2) * 1000.0
        objs.append(Mesh("bunny", np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]), [0, 0, 40], V, F))
    Vb, Fb = heightfield_mesh(blobs_heights((220, 170), (123, 123), 10, 8.0, 20.0, 0), (220, 170))
    objs.append(Mesh("relief", np.eye(3), [0, 0, -40], Vb, Fb, smooth=True))
    eff = Effects(noise=Noise(seed=0), projector_defocus=Defocus(4.0, 800.0), camera_defocus=Defocus(4.0, 800.0),
                  shadows="on")
    ntri = sum(o.n_triangles for o in objs)
    yield f"mesh {ntri // 1000}k tri + shadows + defocus + noise", Scene(system, objs, seq, eff)
    # matched fidelity: exactly the effects of the 1-sample Cycles frame (mesh + cast shadows,
    # Lambertian, falloff; no defocus, no noise)
    yield f"mesh {ntri // 1000}k tri + shadows (matched fidelity)", Scene(system, objs, seq, Effects(shadows="on"))


def _world_meshes(scene):
    """The scene's objects as world-frame triangle meshes for Blender (analytic ones tessellated)."""
    from synth.scenes.meshes import sphere_mesh
    from synth.scenes.objects import Mesh, Plane, Sphere

    out = []
    for o in scene.objects:
        R, t = o.R.numpy(), o.t.numpy()
        if isinstance(o, Mesh):
            V, F, smooth = o.V.numpy(), o.F.numpy(), o.smooth
        elif isinstance(o, Sphere):
            (V, F), smooth = sphere_mesh(o.radius, 512, 256), True
        elif isinstance(o, Plane):
            big = 3000.0
            V, F, smooth = np.array([[-big, -big, 0], [big, -big, 0], [0, big, 0]]), np.array([[0, 1, 2]]), False
        else:
            raise TypeError(type(o))
        out.append((V @ R.T + t, F, o.albedo_value, smooth))
    return out


def _time_ours(scene, repeats):
    from synth.renderer import render
    from synth.renderer.geometry import _RAY_CACHE, compute_geometry

    best: dict = {}

    def keep(k, v):
        best[k] = min(best.get(k, float("inf")), v)

    for _ in range(repeats):
        _RAY_CACHE.clear()
        t0 = time.perf_counter()
        g = compute_geometry(scene)
        keep("geometry cold", time.perf_counter() - t0)
        for k, v in g.timings.items():
            keep(f"geometry: {k}", v)
        t0 = time.perf_counter()
        compute_geometry(scene)
        keep("geometry new pose", time.perf_counter() - t0)
        res = render(scene, geometry=g)
        for k, v in res.timings.items():
            keep(k, v)
    return best, len(res.names), res.plan


def _twin_system(system):
    """What Blender renders: the ideal system (no skew, no distortion) with square camera pixels
    (fy differs from fx by 0.04 % in the built-in system)."""
    from synth.scenes.scene import ideal_system

    system = ideal_system(system)
    K = system.camera.K.copy()
    K[1, 1] = K[0, 0]
    return type(system)(system.camera.with_(K=K), system.projector, dict(system.meta))


def _time_cycles(scene, threads, python, samples=1, frames=3):
    from synth.blender_twin import render_in_blender

    system = _twin_system(scene.system)
    pattern = scene.patterns[[p.name for p in scene.patterns].index("v_f048_n00")]
    img = pattern.projector_image(system.projector.size, scene.effects.A, scene.effects.B)
    d_ref = float(np.linalg.norm(system.projector.center_world))
    dof = scene.effects.camera_defocus if samples > 1 else None
    r = render_in_blender(system, _world_meshes(scene), np.stack([img] * frames), exposure=scene.effects.exposure,
                          reference_distance_mm=d_ref, threads=threads, python=python, samples=samples,
                          camera_dof=None if dof is None else {"focus_mm": dof.focus_mm, "aperture_mm": dof.aperture_mm})
    return min(r["seconds_per_frame"])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-blender", action="store_true")
    ap.add_argument("--quick", action="store_true", help="one repeat, plane and ball only, no Cycles")
    args = ap.parse_args(argv)
    if args.quick:
        args.repeats, args.no_blender = 1, True
    torch.set_num_threads(args.threads)
    blender = None
    if not args.no_blender:
        from synth.blender_twin import blender_available
        blender = sys.executable if blender_available(sys.executable) else None
        if blender is None:
            print("Blender (bpy) not installed: no Cycles comparison")

    from synth import Scene

    print(f"one-time per process, loading the compiled kernels: {_kernel_load_seconds():.2f} s", flush=True)
    rows = []
    for name, scene in _scenes(quick=args.quick):
        # the same frame as Cycles: the twin system; the real one (with lens distortion) beside it
        twin = Scene(_twin_system(scene.system), scene.objects, scene.patterns, scene.effects)
        # ours and Cycles alternate, so that both see the same spells of load on a shared machine
        best: dict = {}
        best_twin: dict = {}
        cyc = float("inf") if blender else None
        for _ in range(args.repeats):
            b, K, plan = _time_ours(scene, 1)
            best = {k: min(v, best.get(k, float("inf"))) for k, v in b.items()}
            b, K, plan = _time_ours(twin, 1)
            best_twin = {k: min(v, best_twin.get(k, float("inf"))) for k, v in b.items()}
            if blender:
                cyc = min(cyc, _time_cycles(scene, args.threads, blender, frames=2))
        whole = best["geometry cold"] + best["total"]
        whole_pose = best["geometry new pose"] + best["total"]
        tw = (best_twin["geometry cold"] + best_twin["total"]) / K
        tw_pose = (best_twin["geometry new pose"] + best_twin["total"]) / K
        if blender and scene.effects.camera_defocus is not None:
            dof_s = _time_cycles(scene, args.threads, blender, samples=DOF_SAMPLES, frames=1)
            print(f"{name}: Cycles with depth of field, {DOF_SAMPLES} samples: {dof_s:.2f} s/frame, "
                  f"speed-up {dof_s / tw:.0f}x (cold) / {dof_s / tw_pose:.0f}x (new pose)")
        rows.append((name, K, best, whole, whole_pose, cyc, tw, tw_pose))
        print(f"{name}: geometry {best['geometry cold']:.3f} s cold / {best['geometry new pose']:.3f} s new pose, "
              f"pattern stage {K / best['patterns']:.0f} images/s, whole stack {K / whole:.1f} images/s"
              + (f", Cycles {cyc:.3f} s/frame" if cyc else ""), flush=True)

    print(f"\nReal system (with lens distortion), 640x480, 72 images, {args.threads} threads:\n")
    print("| scene | geometry s (cold / new pose) | pattern stage images/s | whole stack images/s (cold / new pose) |")
    print("|---|---|---|---|")
    for name, K, b, whole, whole_pose, *_ in rows:
        print(f"| {name} | {b['geometry cold']:.3f} / {b['geometry new pose']:.3f} | {K / b['patterns']:.0f} | "
              f"{K / whole:.0f} / {K / whole_pose:.0f} |")
    if blender:
        print("\nThe same frame as Cycles (twin system: no distortion, square pixels), per frame of the "
              "72-image stack including geometry:\n")
        print("| scene | ours s/frame (cold / new pose) | Cycles s/frame (1 sample) | speed-up (cold / new pose) "
              "| real system with distortion: speed-up (cold / new pose) |")
        print("|---|---|---|---|---|")
        for name, K, b, whole, whole_pose, cyc, tw, tw_pose in rows:
            print(f"| {name} | {tw:.5f} / {tw_pose:.5f} | {cyc:.3f} | {cyc / tw:.0f}x / {cyc / tw_pose:.0f}x "
                  f"| {cyc * K / whole:.0f}x / {cyc * K / whole_pose:.0f}x |")
    print("\nTime per stage (ms, whole 72-image stack, minimum over repeats):")
    for name, K, b, *_ in rows:
        stages = {k: v for k, v in b.items() if k not in ("total", "geometry cold", "geometry new pose")}
        print(f"- {name}: " + ", ".join(f"{k} {1000 * v:.1f}" for k, v in stages.items()))
    if blender:
        from experiments.blender_parity import parity
        print("\nFidelity at full size (what the Cycles times above render; 12 steps, f = 48, v):\n")
        print("| scene (640x480) | mean abs. diff. (8-bit levels) | phase RMS (rad) | pixels |")
        print("|---|---|---|---|")
        for kind in ("plane", "sphere"):
            r = parity(kind, scale=1, steps=12, frequency=48, threads=args.threads, python=blender)
            print(f"| {kind} | {r['mad_8bit']:.3f} | {r['phase_rms_rad']:.1e} | {r['pixels']} |", flush=True)
    return 0


def _kernel_load_seconds() -> float:
    """Seconds to import and first-call the numba kernels (lens inversion, mesh engine, noise)
    on tiny inputs: what a fresh process pays once, before any frame."""
    from calib.distortion import undistort
    from synth.effects.spec import Noise
    from synth.renderer.raycast import nearest_hits
    from synth.effects.sensor import add_noise

    t0 = time.perf_counter()
    undistort(np.zeros((2, 2)), [0.1, 0.0, 0.0, 0.0], fast=True)
    tri = torch.tensor([[[0.0, 0, 1], [1, 0, 1], [0, 1, 1]]], dtype=torch.float64)
    s, idx, bary = nearest_hits(tri, torch.zeros((1, 2), dtype=torch.float64), 1e-3)
    try:
        from synth.renderer._raycast_kernel import mesh_hits
        z3 = np.zeros((1, 3))
        mesh_hits(s.numpy(), idx.numpy(), bary.numpy(), np.zeros((1, 2)), z3, np.zeros(3), np.eye(3),
                  np.zeros((1, 3), dtype=np.int64), z3, True, np.zeros(1), z3.copy(), z3.copy())
    except ImportError:  # no numba: nothing to load
        pass
    add_noise(torch.zeros(4), Noise(), torch.Generator().manual_seed(0))
    return time.perf_counter() - t0


if __name__ == "__main__":
    sys.exit(main())
