"""``calib export``: the twin's training data (or a real capture) as sharded, resumable HDF5.

    calib export CONFIG.toml -o data/train.h5 [--shard i/n] [--set section.key=value]  # resumes
    calib export --combine data/train-*-of-*.h5 -o data/train.h5 # join shards (virtual datasets)
    calib export --capture DIR -o real.h5 [--reference auto|gray|cloud|ladder|none]
    calib export --capture DIR --reference ladder --orientation v [--region left] -o cap_v.h5
"""
from __future__ import annotations

HELP = "twin training data or a real capture as sharded, resumable HDF5"


def add_arguments(parser):
    parser.add_argument("config", nargs="?", help="export config TOML (docs/dataset.md)")
    parser.add_argument("-o", "--output", required=True, help="output .h5 (a shard gets -IIIII-of-NNNNN)")
    parser.add_argument("--shard", help="i/n: export shard i of n (default: RANK/WORLD_SIZE or "
                                        "SLURM_ARRAY_TASK_ID/COUNT from the environment, else 0/1)")
    parser.add_argument("--combine", nargs="+", metavar="SHARD", help="join complete shards into OUTPUT")
    parser.add_argument("--capture", metavar="DIR", help="export a real capture folder (or a folder of them)")
    parser.add_argument("--preset", help="capture layout (design, slstudio, slmaster, kamino-phaseshift, "
                                         "procam-graycode; default: detected)")
    parser.add_argument("--reference", default="auto", choices=("auto", "gray", "cloud", "ladder", "none"),
                        help="reference order of a capture (default: Gray code if any, else --reference-cloud; "
                             "ladder: the capture's own redundant MF ladder, e.g. 1/4/16 labels 1 -> 16)")
    parser.add_argument("--orientation", action="append", choices=("v", "h"),
                        help="export only this orientation (repeatable; default all): one capture per file")
    parser.add_argument("--region", default="all", choices=("all", "left", "right", "top", "bottom"),
                        help="keep one half of the image (the other unlit, no reference): disjoint halves of one "
                             "capture for fine-tuning and a held-out test")
    parser.add_argument("--ladder-min-modulation", type=float, default=0.02,
                        help="ladder reference: least modulation of every frequency (fraction of full scale)")
    parser.add_argument("--ladder-max-residual", type=float, default=0.2,
                        help="ladder reference: largest distance of every step's prior from an integer (periods)")
    parser.add_argument("--reference-cloud", help="point cloud (.mat 'xyz' or .npy, H x W x 3 mm) of the same view")
    parser.add_argument("--reference-system", help="calibration of the capture (for --reference-cloud)")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="override one key of CONFIG, e.g. --set export.samples=10 (repeatable)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    import json

    from synth.export.writer import ExportError, combine, parse_shard, shard_from_environment, shard_path

    from ..outputs import claim

    modes = sum(x is not None for x in (args.config, args.combine, args.capture))
    if modes != 1:
        raise ExportError("give exactly one of CONFIG, --combine SHARDS or --capture DIR")
    if args.combine:
        claim(args.output, "file", inputs=args.combine)
        out = combine(args.combine, args.output)
        print(f"combined {len(args.combine)} shard(s) into {out} (virtual datasets, no data copied)")
        return 0
    if args.capture:
        from synth.export.capture import export_capture

        claim(args.output, "file", inputs=[args.capture, args.reference_cloud, args.reference_system])

        s = export_capture(args.capture, args.output, preset=args.preset, reference=args.reference,
                           reference_cloud=args.reference_cloud, reference_system=args.reference_system,
                           orientations=args.orientation, region=args.region,
                           ladder_min_modulation=args.ladder_min_modulation,
                           ladder_max_step_residual=args.ladder_max_residual)
        print(f"{s['file']}: {s['samples']} capture sample(s)")
        for c in s["captures"]:
            print(f"  {c['folder']} [{c['preset']}]: " + json.dumps(c["orientations"]))
        return 0
    from synth.export.dataset import export_dataset, format_summary

    shard = parse_shard(args.shard) if args.shard else (shard_from_environment() or (0, 1))
    claim(shard_path(args.output, *shard), "file", inputs=[args.config])
    print(format_summary(export_dataset(args.config, args.output, shard=shard, progress=not args.quiet,
                                        overrides=args.set)))
    return 0
