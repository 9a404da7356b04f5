"""``calib train [CONFIG.toml] [section.key=value ...] -o RUN`` / ``--resume RUN``: train the learned
fringe-order network (unwrap.learned.train). Several processes: ``torchrun --nproc_per_node=N -m
sltwin.cli train CONFIG.toml -o RUN`` (gloo on CPU, NCCL on CUDA; only rank 0 writes)."""
from __future__ import annotations

import os

from sltwin.errors import CommandError

from ..outputs import claim

HELP = "train the learned fringe-order network (config + overrides, resumable, torchrun for DDP)"

#: ``calib`` passes items left after the options (``CONFIG -o RUN key=value``) to ``items``.
TRAILING_ITEMS = "items"


def add_arguments(parser):
    parser.add_argument("items", nargs="*", metavar="CONFIG|KEY=VALUE",
                        help="a TOML config (optional) followed by section.key=value overrides, "
                             "e.g. optim.steps=2000 data.train='[\"train.h5\"]'")
    parser.add_argument("-o", "--output", default=None, help="run folder (default runs/<date-time>)")
    parser.add_argument("--init", default=None, metavar="MODEL",
                        help="fine-tune: start from this checkpoint's weights ('learned': the shipped model; "
                             "fresh optimiser, optim.lr 2e-4 unless set); same as model.init=MODEL")
    parser.add_argument("--resume", default=None, metavar="RUN", help="continue the run in this folder")
    parser.add_argument("--deterministic", action="store_true", help="deterministic kernels (slower)")
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bar or progress messages (the result lines stay)")


def split_items(items):
    """(config path or None, overrides) from the positional items."""
    config, overrides = None, []
    for i, it in enumerate(items):
        if "=" in it:
            overrides.append(it)
        elif i == 0:
            config = it
        else:
            raise CommandError(f"{it!r}: expected section.key=value after the config file")
    return config, overrides


def run(args) -> int:
    import json

    from unwrap.learned.train import train

    config, overrides = split_items(args.items)
    if args.resume and args.output:
        raise CommandError("--resume RUN continues in RUN; do not give -o as well")
    if args.init:
        if args.resume:
            raise CommandError("--init starts a new run from a model's weights; --resume continues a run: not both")
        overrides = overrides + [f"model.init={json.dumps(str(args.init))}"]
    if os.environ.get("RANK", "0") == "0":     # only rank 0 writes (torchrun): it alone holds the run folder
        if args.resume:
            claim(args.resume, "dir", option="--resume")
        elif args.output:
            claim(args.output, "dir", inputs=[config, args.init if args.init not in (None, "learned") else None])
    r = train(config, overrides, args.output, resume=args.resume,
              deterministic=True if args.deterministic else None, progress=not args.quiet)
    if r.run_dir is not None:
        best = "n/a" if r.best_error == float("inf") else f"{100 * r.best_error:.3f} %"
        print(f"step {r.step}: final loss {r.final_loss:.4g}, best validation error {best}, "
              f"{r.samples_per_s:.2f} training samples/s")
        print(f"wrote {r.run_dir} (model.pt, last.pt, best.pt, train.csv, val.csv, metrics.json, metrics.png)")
    return 0
