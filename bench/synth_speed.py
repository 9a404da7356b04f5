"""Speed of the synth renderer at 640x480 (the paper's camera) against Blender Cycles in the
same run: ``python -m bench.synth_speed [--no-blender] [--threads 2]``.

Rows: the paper's 72-image stack (v/h, 12 steps, f = 1, 8, 48) on a plane, on the ball, and on a
~100k-triangle mesh (bunny, 69k, on a blobs relief, 30k) with shadows + projector and camera
defocus + noise. Columns: geometry time, pattern-stage images/s, whole-stack images/s, and the
per-stage times. Blender: one frame of the same plane / ball scene at full size (1 sample,
point-sampled, direct light: the fidelity that matches ours per the parity test), timed by Cycles.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch


def _scenes():
    from calib import default_system
    from synth import Mesh, Plane, Scene, Sphere, blobs_heights, heightfield_mesh, load_mesh, phase_sequence
    from synth.effects import Defocus, Effects, Noise

    system = default_system()
    seq = phase_sequence(("v", "h"), (1, 8, 48), 12)
    yield "plane", Scene(system, [Plane("plane", np.eye(3), [0, 0, 0])], seq)
    yield "ball", Scene(system, [Sphere("ball", np.eye(3), [0, 0, 0])], seq)
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-blender", action="store_true")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    from synth import render
    from synth.geometry import compute_geometry

    rows = []
    for name, scene in _scenes():
        t0 = time.perf_counter()
        g = compute_geometry(scene, log=_Quiet())
        t_geo = time.perf_counter() - t0
        res = render(scene, geometry=g, log=_Quiet())
        res = render(scene, geometry=g, log=_Quiet())  # warm
        K = len(res.names)
        t_pat = res.timings["patterns"]
        total = t_geo + res.timings["total"]
        rows.append((name, K, t_geo, K / t_pat, K / total, dict(g.timings), dict(res.timings)))
        print(f"{name}: geometry {t_geo:.2f} s, pattern stage {K / t_pat:.0f} images/s, "
              f"whole stack {K / total:.1f} images/s", flush=True)
    print("\n| scene (640x480, 72 images) | geometry s | pattern stage images/s | whole stack images/s |")
    print("|---|---|---|---|")
    for name, K, tg, ips, ipt, _, _ in rows:
        print(f"| {name} | {tg:.2f} | {ips:.0f} | {ipt:.1f} |")
    print("\nTime per stage (s, whole 72-image stack):")
    for name, K, tg, ips, ipt, gt, rt in rows:
        stages = {**{f"geometry: {k}": v for k, v in gt.items()}, **{k: v for k, v in rt.items() if k != "total"}}
        print(f"- {name}: " + ", ".join(f"{k} {v:.3f}" for k, v in stages.items()))
    if not args.no_blender:
        from synth.blender_twin import blender_available
        from synth.parity import parity
        if not blender_available(sys.executable):
            print("\nBlender (bpy) not installed: no Cycles comparison")
            return 0
        print("\n| scene (640x480) | Cycles s/frame | ours s/frame (whole stack incl. geometry) | speed-up | "
              "parity MAD 8-bit | parity phase RMS rad |")
        print("|---|---|---|---|---|---|")
        for kind, row in (("plane", rows[0]), ("sphere", rows[1])):
            r = parity(kind, scale=1, steps=12, frequency=48, threads=args.threads, python=sys.executable)
            ours = 1.0 / row[4]
            cyc = r["blender_seconds_per_frame"]
            print(f"| {kind} | {cyc:.3f} | {ours:.4f} | {cyc / ours:.0f}x | {r['mad_8bit']:.3f} | "
                  f"{r['phase_rms_rad']:.2e} |", flush=True)
    return 0


class _Quiet:
    def info(self, *a):
        pass


if __name__ == "__main__":
    sys.exit(main())
