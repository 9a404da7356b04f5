"""``calib render SCENE.toml -o OUT/``: render a scene to PNG images + HDF5 ground truth, and a
``capture.toml`` describing the phase-shift frames (DESIGN.md layout) when they form one ladder,
so that ``calib unwrap OUT/`` reads the folder as it is."""
from __future__ import annotations

from ..outputs import claim, fresh_dir

HELP = "render a scene TOML to PNG images + HDF5 ground truth"


def add_arguments(parser):
    parser.add_argument("scene", help="scene TOML file (schema: docs/synth.md)")
    parser.add_argument("-o", "--output", required=True, help="output folder (images + truth.h5)")
    parser.add_argument("--seed", type=int, default=None, help="override the noise seed")
    parser.add_argument("--no-truth", action="store_true", help="write the images only")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an earlier render (or rendered session) in OUT wholly; without it a folder "
                             "that holds one is refused")
    parser.add_argument("-q", "--quiet", action="store_true", help="do not print the render plan or progress")


def run(args) -> int:
    from dataclasses import replace
    from pathlib import Path

    from synth.scenes.board_session import scene_capture_toml
    from synth.renderer.output import write_pngs, write_truth_h5
    from synth.renderer.render import render
    from synth.scenes.scene import load_scene
    from unwrap.safe_output import write_text

    import logging

    claim(args.output, "dir", inputs=[args.scene])
    scene = load_scene(args.scene)
    fresh_dir(args.output, "a render", args.overwrite)
    if args.seed is not None and scene.effects.noise is not None:
        scene.effects = replace(scene.effects, noise=replace(scene.effects.noise, seed=args.seed))
    logging.getLogger("sltwin").info(f"rendering {len(scene.patterns)} image(s) of {scene.name!r} "
                                     f"({scene.system.camera.width}x{scene.system.camera.height} px) -> {args.output}")
    result = render(scene)
    out = Path(args.output)
    write_pngs(result, out)
    description = scene_capture_toml(scene)
    if description is not None:   # calib unwrap reads the folder as it is
        write_text(out / "capture.toml", description)
    if not args.no_truth:
        write_truth_h5(result, scene, out / "truth.h5")
    if not args.quiet:
        for line in result.plan:
            print(f"  {line}")
        t = result.timings
        print(f"rendered {len(result.names)} image(s) of {scene.name!r} in {t['total']:.2f} s "
              f"(patterns {t['patterns']:.3f} s) -> {out}")
    return 0
