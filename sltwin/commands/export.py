"""``calib export``: the twin's training data (or a real capture) as sharded, resumable HDF5.

    calib export CONFIG.toml -o data/train.h5 [--shard i/n] [--set section.key=value]  # resumes
    calib export --combine data/train-*-of-*.h5 -o data/train.h5 # join shards (virtual datasets)
    calib export --capture DIR -o real.h5 [--reference auto|gray|cloud|none]
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
    parser.add_argument("--preset", help="capture layout (design, slstudio, slmaster, kamino; default: detected)")
    parser.add_argument("--reference", default="auto", choices=("auto", "gray", "cloud", "none"),
                        help="reference order of a capture (default: Gray code if any, else --reference-cloud)")
    parser.add_argument("--reference-cloud", help="point cloud (.mat 'xyz' or .npy, H x W x 3 mm) of the same view")
    parser.add_argument("--reference-system", help="calibration of the capture (for --reference-cloud)")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="override one key of CONFIG, e.g. --set export.samples=10 (repeatable)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    import json

    from synth.export.writer import ExportError, combine, parse_shard

    modes = sum(x is not None for x in (args.config, args.combine, args.capture))
    if modes != 1:
        raise ExportError("give exactly one of CONFIG, --combine SHARDS or --capture DIR")
    if args.combine:
        out = combine(args.combine, args.output)
        print(f"combined {len(args.combine)} shard(s) into {out} (virtual datasets, no data copied)")
        return 0
    if args.capture:
        from synth.export.capture import export_capture

        s = export_capture(args.capture, args.output, preset=args.preset, reference=args.reference,
                           reference_cloud=args.reference_cloud, reference_system=args.reference_system)
        print(f"{s['file']}: {s['samples']} capture sample(s)")
        for c in s["captures"]:
            print(f"  {c['folder']} [{c['preset']}]: " + json.dumps(c["orientations"]))
        return 0
    from synth.export.dataset import export_dataset, format_summary

    shard = parse_shard(args.shard) if args.shard else None
    print(format_summary(export_dataset(args.config, args.output, shard=shard, progress=not args.quiet,
                                        overrides=args.set)))
    return 0
