"""``calib export-model MODEL -o model.onnx``: a trained model (``learned`` = the shipped one, or a
checkpoint ``.pt``) as ONNX, for ``calib unwrap --model model.onnx`` on onnxruntime (CPU, CUDA
where present) without torch (unwrap.learned.runtime; docs/learned.md)."""
from __future__ import annotations

from sltwin.errors import CommandError

from ..outputs import claim

HELP = "write a trained unwrapping model as ONNX (onnxruntime inference without torch)"


def add_arguments(parser):
    parser.add_argument("model", metavar="MODEL", help="'learned' (the shipped model) or a checkpoint (.pt)")
    parser.add_argument("-o", "--output", required=True, help="the .onnx file to write")
    parser.add_argument("--opset", type=int, default=18, help="ONNX opset (default 18)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress messages")


def run(args) -> int:
    import logging
    import warnings
    from pathlib import Path

    if not str(args.output).lower().endswith(".onnx"):
        raise CommandError(f"-o {args.output}: expected a file name ending in .onnx")
    out = claim(args.output, "file", inputs=[args.model if Path(args.model).exists() else None])
    from unwrap.learned.runtime import export_onnx, load_predictor

    pred = load_predictor(args.model)      # refuses a foreign / damaged checkpoint (exit 2) before exporting
    if pred.backend != "torch":
        raise CommandError(f"{args.model}: already an ONNX model")
    for name in ("torch.onnx", "torch._dynamo", "torch.export", "onnxscript"):
        logging.getLogger(name).setLevel(logging.ERROR)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        path = export_onnx((pred.net, pred.ck), out, opset=args.opset)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB; {pred.arch['kind']} model, inputs (1, "
          f"{pred.arch['in_channels']}, H, W) float32, any H x W)")
    return 0
