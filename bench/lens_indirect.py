"""The thin lens's shared indirect light against the exact one: ``python -m bench.lens_indirect
[--points 8] [--real 0 1 2] [--size 160 120] [--no-ball] [--quick] [-q]``.

Per scene, three renders with the same thin lens (8 steps of vertical fringes at f = 1, linear
images, no noise): direct light only (D), interreflection computed per aperture point (E,
``interreflection.thin_lens = "exact"``) and shared (S, the lens centre's indirect light looked
up per aperture point, synth.effects.lens_indirect); and the pinhole render with interreflection
(no thin lens) as the cost anchor. Reported: the per-pixel difference S - E relative to the
indirect component E - D (RMS over the hit pixels of all frames, and its 99th percentile over
the RMS), and the unit-frequency phase bias of the indirect light ``wrap(phi_X - phi_D)``
(experiments.gi_bias.bias_map) of S against E's: correlation and RMS difference over the bias
RMS, on the lit pixels and on the outline band (within 8 px of an object or lit-state change);
the aperture hits computed exactly (not seen by the lens centre); seconds (process CPU) of each
render.

Scenes: ball-wall-dof (experiments.defocus_bias: the 25.4 mm ball 34.6 mm before a wall, 160x120,
80 mm camera aperture focused on the ball or on the wall, 1-bounce interreflection) and samples
``--real`` of synth/data/export_real.toml (their drawn scene, defocus and interreflection, the
camera scaled to ``--size``, noise off; a sample without interreflection gets the default one,
without a thin lens the config's 8 points on both devices).
"""
from __future__ import annotations

import argparse
import re
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def _band(geometry, r: int = 8) -> np.ndarray:
    from scipy.ndimage import binary_dilation

    W, H = geometry.size
    obj = geometry.object_id.numpy().reshape(H, W)
    lit = geometry.lit.numpy().reshape(H, W)
    edge = np.zeros((H, W), bool)
    for a in (obj, lit):
        edge[:, 1:] |= a[:, 1:] != a[:, :-1]
        edge[1:, :] |= a[1:, :] != a[:-1, :]
    return binary_dilation(edge, iterations=r)


def compare_scene(name: str, scene) -> dict:
    """The three thin-lens renders and the pinhole one of ``scene`` (its patterns replaced by 8
    steps at f = 1) and their comparison (module docstring)."""
    from experiments.gi_bias import bias_map, compare
    from synth import render
    from synth.effects.spec import Interreflection
    from synth.scenes.sequence import phase_sequence
    from synth.effects.thin_lens import without_sampling

    ir = scene.effects.interreflection or Interreflection()
    scene = replace(scene, patterns=phase_sequence(("v",), (1,), 8))
    out, imgs = {"scene": name}, {}
    for key, eff in (("direct", replace(scene.effects, interreflection=None)),
                     ("exact", replace(scene.effects, interreflection=replace(ir, thin_lens="exact"))),
                     ("shared", replace(scene.effects, interreflection=replace(ir, thin_lens="shared")))):
        c0 = time.process_time()
        res = render(replace(scene, effects=eff), quantised=False)
        out[f"{key}_cpu_s"] = time.process_time() - c0
        imgs[key] = res.images.numpy().astype(np.float64)
        if key == "shared":
            out["plan"] = [line for line in res.plan if line.startswith("interreflection")]
            geom = res.geometry
    c0 = time.process_time()
    render(without_sampling(replace(scene, effects=replace(scene.effects, interreflection=ir))), quantised=False)
    out["pinhole_cpu_s"] = time.process_time() - c0
    W, H = geom.size
    hit = geom.hit.numpy().reshape(H, W)
    ind = (imgs["exact"] - imgs["direct"])[:, hit]
    diff = (imgs["shared"] - imgs["exact"])[:, hit]
    rms_ind = float(np.sqrt(np.mean(ind ** 2)))
    out["img_rms_rel"] = float(np.sqrt(np.mean(diff ** 2))) / rms_ind
    out["img_p99_rel"] = float(np.percentile(np.abs(diff), 99)) / rms_ind
    b_ex, b_sh = bias_map(imgs["exact"], imgs["direct"]), bias_map(imgs["shared"], imgs["direct"])
    lit = geom.lit.numpy().reshape(H, W)
    band = _band(geom) & lit
    out["all"] = compare(b_ex, b_sh, lit)
    out["band"] = compare(b_ex, b_sh, band)
    out["indirect_rms"] = rms_ind
    return out


def ball_scenes(points: int):
    from experiments.defocus_bias import EXPOSURE, _setup, defocus_scene
    from synth import Scene
    from synth.effects.spec import Defocus, Effects, Interreflection

    system, d_ref, patterns = _setup(8)
    sc = defocus_scene("ball-wall-dof")
    for label, focus in (("ball-wall-dof, focus on the ball", 822.2), ("ball-wall-dof, focus on the wall", 906.9)):
        eff = Effects(exposure=EXPOSURE, fringe_sampling="analytic", reference_distance_mm=d_ref,
                      camera_defocus=Defocus(80.0, focus, 6, points), interreflection=Interreflection())
        yield label, Scene(system, sc.objects, patterns, eff)


def real_scenes(indices, size, points: int):
    """Samples of synth/data/export_real.toml: scene as drawn (module docstring), scaled camera."""
    from synth.effects.spec import Interreflection
    from synth.export.config import load_config
    from synth.export.dataset import base_system
    from synth.export.defocus_model import choose_defocus_model, sampled
    from synth.export.sample import draw_covered

    cfg = load_config(REPO / "synth" / "data" / "export_real.toml", [])
    system, sampler = base_system(cfg)
    for i in indices:
        scene, geom, params, _ = draw_covered(cfg, system, i, {}, sampler)
        scene = choose_defocus_model(cfg, scene, geom, params)
        eff = scene.effects
        if not sampled(scene):
            eff = replace(eff, camera_defocus=replace(eff.camera_defocus, samples=points),
                          projector_defocus=replace(eff.projector_defocus, samples=points))
        eff = replace(eff, noise=None, interreflection=eff.interreflection or Interreflection())
        cam = scene.system.camera
        W, H = cam.size
        s = size[0] / W
        K = np.array(cam.K, dtype=np.float64)
        K[:2, :2] *= s
        K[:2, 2] = (K[:2, 2] + 0.5) * s - 0.5
        system_s = replace(scene.system, camera=cam.with_(K=K, size=tuple(size)))
        ir = eff.interreflection
        yield (f"export_real #{i} ({params.get('layout', {}).get('kind', '?')}, {ir.bounces} bounce(s), "
               f"{len(scene.objects)} objects)"), replace(scene, system=system_s, effects=eff)


def table(rows) -> str:
    lines = ["| scene | indirect: RMS / p99 of shared - exact (of its RMS) | phase bias RMS (rad) all / band | "
             "correlation all / band | RMS diff / bias RMS all / band | exact aperture hits | CPU s pinhole / "
             "shared / exact |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        a, b = r["all"], r["band"]
        m = re.search(r"(\d+) of (\d+) aperture hit", r["plan"][0]) if r["plan"] else None
        ex = f"{int(m[1]) / int(m[2]):.2%}" if m else "?"
        lines.append(f"| {r['scene']} | {r['img_rms_rel']:.3f} / {r['img_p99_rel']:.3f} | "
                     f"{a['bias_rms']:.4f} / {b['bias_rms']:.4f} | {a['correlation']:.4f} / {b['correlation']:.4f} | "
                     f"{a['diff_over_bias']:.3f} / {b['diff_over_bias']:.3f} | {ex} | "
                     f"{r['pinhole_cpu_s']:.1f} / {r['shared_cpu_s']:.1f} / {r['exact_cpu_s']:.1f} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=8)
    ap.add_argument("--real", type=int, nargs="*", default=[0, 1, 2])
    ap.add_argument("--size", type=int, nargs=2, default=[160, 120])
    ap.add_argument("--no-ball", action="store_true")
    ap.add_argument("--quick", action="store_true", help="4 points, the ball focused on the ball only, no export sample")
    ap.add_argument("-q", action="store_true")
    a = ap.parse_args(argv)
    if a.quick:
        a.points, a.real = 4, []
    rows = []
    scenes = [] if a.no_ball else list(ball_scenes(a.points))[:1 if a.quick else 2]
    for name, scene in scenes + list(real_scenes(a.real, a.size, a.points)):
        rows.append(compare_scene(name, scene))
        if not a.q:
            print(name, rows[-1]["plan"], file=sys.stderr, flush=True)
    print(table(rows))
    return rows


if __name__ == "__main__":
    main()
