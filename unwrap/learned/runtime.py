"""Run a trained model on one frame's inputs: torch (a ``.pt`` checkpoint) or onnxruntime (an
``.onnx`` file written by :func:`export_onnx`, ``calib export-model``), loaded once per process.

A predictor maps the network input (1, C, H, W) float32 (:func:`unwrap.learned.fast_features.make_inputs`)
to logits (1, K, H, W) and carries what the checks need: ``arch`` (kind, max_correction, ...) and
``meta`` (the trained frequency pairs). :func:`load_predictor` caches it by path, size and
modification time, so orientations and captures of one process share one loaded model.

- torch: the network in eval mode under ``torch.inference_mode`` (no autograd; on the CPU in
  float32 a channels-last copy with BatchNorm folded, its input written in that layout:
  :class:`TorchPredictor`), on ``device``
  ("cpu", "cuda", or "auto": CUDA where torch sees one), in ``precision`` "fp32" (default), or
  "fp16" / "bf16" under autocast (the convolutions in half precision, the norms and the logits in
  float32; fp16 only on CUDA). Half precision can move a pixel's order where two classes' logits
  tie within its rounding: ``python -m bench.learned_gpu`` counts those pixels per frame.
- onnxruntime: ``CUDAExecutionProvider`` first where the installed onnxruntime offers it, else
  ``CPUExecutionProvider``. Importing this module, loading an ``.onnx`` model and running it
  import neither torch nor anything that does (``calib unwrap --model model.onnx`` runs without
  torch; tested in a subprocess).

The ONNX file holds the graph with dynamic height and width (any frame size) and, in its
metadata, ``sltwin_format`` (= :data:`ONNX_FORMAT`), ``sltwin_arch`` and ``sltwin_meta`` (JSON:
the checkpoint's ``arch`` and ``meta``).
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from .errors import CheckpointError, ModelError

ONNX_FORMAT = "sltwin-unwrap-model-onnx-1"
#: Arithmetic of a torch forward: float32, or float16 / bfloat16 under autocast.
PRECISIONS = ("fp32", "fp16", "bf16")
#: Where a model runs: the CPU, a CUDA device, or CUDA where one is present.
DEVICES = ("cpu", "cuda", "auto")
_SHIPPED = Path(__file__).resolve().parent / "data" / "shipped" / "model.pt"
_CACHE: dict = {}


def shipped_model_path() -> Path:
    """The checkpoint that ships with sltwin (trained on the twin; see docs/learned.md)."""
    if not _SHIPPED.is_file():
        raise ModelError(f"the shipped model is missing ({_SHIPPED}); reinstall sltwin or pass a checkpoint path")
    return _SHIPPED


def model_path(model) -> Path:
    """The file of ``model``: "learned" / "default" / None (the shipped checkpoint) or a path."""
    return shipped_model_path() if model in (None, "learned", "default") else Path(model)


def is_onnx(model) -> bool:
    return isinstance(model, (str, os.PathLike)) and str(model).lower().endswith(".onnx")


class TorchPredictor:
    """A torch network (eval mode) and its checkpoint dict; ``logits(x)`` under inference mode.

    ``channels_last``: run the convolutions in channels-last memory format; ``fold_norm``: fold
    each BatchNorm into the convolution before it (eval statistics). Both run on a private copy
    of ``net`` (:func:`unwrap.learned.cpu_net.prepare_for_cpu`; ``self.net`` stays the network
    given; the copy is made again where ``net`` is changed in place: :class:`~unwrap.learned.cpu_net.CpuCopy`)
    and change only the float rounding (logits move by ~1e-5). None (the default): both
    on for a float32 forward on the CPU of a network in eval mode, off elsewhere - measured for the shipped width-8 model
    and the width-16 one (docs/speed.md, "The learned path on 2 CPU cores": channels-last with
    its input already in that layout ~2x faster; on CUDA see bench.learned_gpu).
    ``input_layout`` ("nchw" / "nhwc") is the memory layout the forward takes without a copy
    (:func:`unwrap.learned.fast_features.make_inputs`' ``layout``); ``multiple``: the size
    multiple the network pads its input to."""

    backend = "torch"
    #: a heap trim before the first forward of each frame size only (unwrap.learned.infer._TRIMMED)
    trim_every_frame = False

    def __init__(self, net, ck: dict, channels_last: bool | None = None, precision: str = "fp32",
                 fold_norm: bool | None = None):
        import torch

        self.net, self.ck = net, ck
        self.arch, self.meta = ck["arch"], ck["meta"]
        self.device = next(net.parameters()).device
        if precision not in PRECISIONS:
            raise ModelError(f"precision {precision!r}: expected one of {', '.join(PRECISIONS)}")
        if precision == "fp16" and self.device.type != "cuda":
            raise ModelError("precision fp16 needs a CUDA device (the CPU has no fast float16 convolutions); "
                             "use bf16 or fp32 on the CPU")
        if precision == "bf16" and self.device.type == "cuda" and not torch.cuda.is_bf16_supported():
            raise ModelError(f"precision bf16: this GPU ({torch.cuda.get_device_name(self.device)}) has no "
                             "bfloat16 arithmetic; use fp16 or fp32")
        self.precision = precision
        self._dtype = {"fp16": torch.float16, "bf16": torch.bfloat16}.get(precision)
        # a network still in train mode (being trained or fine-tuned) runs as it is by default: a private
        # folded copy would keep its weights of now, and folding uses the running statistics
        cpu32 = self.device.type == "cpu" and precision == "fp32" and not net.training
        self.channels_last = cpu32 if channels_last is None else bool(channels_last)
        self.fold_norm = (cpu32 if fold_norm is None else bool(fold_norm)) and self.arch.get("norm") == "batch"
        self.input_layout = "nhwc" if self.channels_last else "nchw"
        self.multiple = 2 ** (int(self.arch.get("depth", 0)) + 1)
        self._run = net
        if self.channels_last or self.fold_norm:
            from .cpu_net import CpuCopy         # made again where net is changed in place (fine-tuned)

            self._run = CpuCopy(net, channels_last=self.channels_last, fold=self.fold_norm)

    @property
    def features_on_device(self) -> bool:
        """Whether :func:`unwrap.learned.infer.unwrap_learned` builds the inputs and decodes on the
        device too (CUDA, MF pairs: the numpy features would cost 15-20x the forward; docs/speed.md)."""
        return self.device.type == "cuda"

    def forward(self, t):
        """Logits (B, K, H, W) float32 tensor of an input tensor on the device, in the precision."""
        import torch

        with torch.inference_mode(), torch.autocast(self.device.type, dtype=self._dtype,
                                                     enabled=self._dtype is not None):
            if self.channels_last:      # a no-op on an input already channels-last (layout "nhwc")
                t = t.contiguous(memory_format=torch.channels_last)
            return self._run(t).float()

    def logits(self, x):
        """Logits (B, K, H, W) float32 numpy of ``x`` (B, C, H, W) float32 numpy (any B, either memory
        layout); channels-last logits are a (B, K, H, W) view of a (B, H, W, K) block."""
        import torch

        return self.forward(torch.from_numpy(x).to(self.device)).cpu().numpy()


class OnnxPredictor:
    """An onnxruntime session of an exported model; ``logits(x)``.

    Session: all graph optimisations, sequential execution, no memory arena (the peak stays one
    forward's), ``threads`` intra-op threads (None: onnxruntime's default, one per core).
    ``spin``: whether idle pool threads spin waiting for work. On an idle 2-core machine spinning
    is faster (forward 105 vs 119 ms, 640x480); on a machine shared with other jobs a spinning
    pool measured 1.5x slower (891 vs 587 ms at load ~15; docs/speed.md). None: spin only when the
    1-minute load average, taken when the session is made, is below the number of cores."""

    backend = "onnxruntime"
    #: a heap trim before every forward: the arena does not reuse the heap's freed blocks
    #: (unwrap.learned.infer._TRIMMED)
    trim_every_frame = True

    def __init__(self, path, providers=None, threads=None, spin=None, device=None):
        import os

        import onnxruntime as ort

        path = Path(path)
        if not path.is_file():
            raise CheckpointError(f"model not found: {path}")
        avail = ort.get_available_providers()
        if providers is None:
            providers = [p for p in ("CUDAExecutionProvider", "CPUExecutionProvider") if p in avail]
            if device == "cpu":
                providers = ["CPUExecutionProvider"]
            elif device == "cuda":
                if "CUDAExecutionProvider" not in avail:
                    raise ModelError(f"device cuda: this onnxruntime has no CUDAExecutionProvider (it offers "
                                     f"{', '.join(avail)}); install onnxruntime-gpu, or run a .pt checkpoint "
                                     "with torch on CUDA")
                providers = ["CUDAExecutionProvider"]
        opts = ort.SessionOptions()
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        opts.enable_cpu_mem_arena = False     # activations freed after each frame: the peak stays one forward's
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        if spin is None:    # no load average (not POSIX): onnxruntime's own default, spinning
            spin = os.getloadavg()[0] < (os.cpu_count() or 1) if hasattr(os, "getloadavg") else True
        self.spin = bool(spin)
        opts.add_session_config_entry("session.intra_op.allow_spinning", "1" if spin else "0")
        if threads:
            opts.intra_op_num_threads = int(threads)
        try:
            self.session = ort.InferenceSession(str(path), sess_options=opts, providers=providers)
        except Exception as exc:      # onnxruntime's own error types (InvalidProtobuf, Fail, ...)
            raise CheckpointError(f"{path}: not a readable ONNX model ({type(exc).__name__}: "
                                  f"{str(exc)[:200]})") from None
        props = self.session.get_modelmeta().custom_metadata_map
        if props.get("sltwin_format") != ONNX_FORMAT:
            raise CheckpointError(f"{path}: not an sltwin unwrapping model (ONNX metadata sltwin_format "
                                  f"{props.get('sltwin_format')!r}, expected {ONNX_FORMAT!r}); write one with "
                                  "calib export-model")
        self.arch, self.meta = json.loads(props["sltwin_arch"]), json.loads(props["sltwin_meta"])
        self.providers = self.session.get_providers()
        self.input_name = self.session.get_inputs()[0].name
        self.multiple = 2 ** (int(self.arch["depth"]) + 1)
        self.input_layout = "nchw"

    def prepare(self, x):
        """``x`` as the graph takes it: sizes that are multiples of 2**(depth+1), zeros padded at the
        bottom and right (as :class:`~unwrap.learned.network.FringeUNet` pads), C-contiguous. A
        caller that drops its own ``x`` for this one holds one copy of the input, not two."""
        import numpy as np

        H, W = x.shape[-2:]
        ph, pw = (-H) % self.multiple, (-W) % self.multiple
        if ph or pw:
            x = np.pad(x, ((0, 0), (0, 0), (0, ph), (0, pw)))
        return np.ascontiguousarray(x)

    def logits(self, x):
        """Logits (1, K, H, W) of ``x`` (1, C, H, W), padded by :meth:`prepare` and cropped back."""
        H, W = x.shape[-2:]
        return self.session.run(None, {self.input_name: self.prepare(x)})[0][..., :H, :W]


def resolve_device(device) -> str:
    """"cpu" or "cuda" for a torch model: ``device`` None / "cpu" -> "cpu"; "auto" -> "cuda" where
    torch sees a CUDA device, else "cpu"; "cuda" (or "cuda:N") refused where there is none."""
    if device in (None, "cpu"):
        return "cpu"
    if device != "auto" and not str(device).startswith("cuda"):
        raise ModelError(f"device {device!r}: expected one of {', '.join(DEVICES)}")
    import torch

    if torch.cuda.is_available():
        return "cuda" if device == "auto" else str(device)
    if device == "auto":
        return "cpu"
    raise ModelError(f"device {device}: torch sees no CUDA device (torch {torch.__version__}, "
                     f"built for CUDA {torch.version.cuda or 'none'}); use --device cpu or auto")


def load_predictor(model="learned", device=None, precision: str = "fp32"):
    """A predictor for ``model``: "learned" (the shipped checkpoint), a ``.pt`` / ``.onnx`` path, a
    ``(net, checkpoint)`` pair (run as it is: no channels-last copy, no folding), or a predictor
    (returned as is). Files are loaded once per process
    (cached by path, size, modification time, device and precision).

    ``device``: None (torch: the CPU; onnxruntime: CUDA where its build offers it, else the CPU),
    "cpu", "cuda" or "auto" (:data:`DEVICES`); ``precision``: :data:`PRECISIONS` (torch only: an
    ONNX graph runs in float32)."""
    if hasattr(model, "logits") and hasattr(model, "arch"):
        return model
    if isinstance(model, tuple):     # the caller's network, maybe still training: run as it is
        return TorchPredictor(*model, precision=precision, channels_last=False, fold_norm=False)
    if device not in (None, *DEVICES) and not str(device).startswith("cuda"):
        raise ModelError(f"device {device!r}: expected one of {', '.join(DEVICES)}")
    if precision not in PRECISIONS:
        raise ModelError(f"precision {precision!r}: expected one of {', '.join(PRECISIONS)}")
    path = model_path(model)
    try:
        st = path.stat()
        # a .pt on None and "cpu" is one predictor (an .onnx's None means "CUDA where offered")
        key = (str(path.resolve()), st.st_size, st.st_mtime_ns, device if is_onnx(path) else device or "cpu",
               precision)
    except OSError:
        key = None
    if key is not None and key in _CACHE:
        return _CACHE[key]
    if is_onnx(path):
        if precision != "fp32":
            raise ModelError(f"precision {precision}: an ONNX model runs in float32 (half precision is for a "
                             ".pt checkpoint on torch)")
        pred = OnnxPredictor(path, device=None if device == "auto" else device)
    else:
        from .checkpoint import load_model

        pred = TorchPredictor(*load_model(path, resolve_device(device)), precision=precision)
    if key is not None:
        _CACHE[key] = pred
    return pred


def export_onnx(model, out, *, opset: int = 18) -> Path:
    """Write ``model`` (a checkpoint path, "learned", or a (net, checkpoint) pair) as ONNX with
    dynamic height and width and the checkpoint's arch / meta in its metadata; atomically
    (temporary file, fsync, rename). Returns the path."""
    from ..safe_output import atomic_path

    import onnx
    import torch

    from .checkpoint import load_model

    net, ck = model if isinstance(model, tuple) else load_model(model_path(model), "cpu")
    net = net.cpu().eval()
    C, m = int(ck["arch"]["in_channels"]), 2 ** (int(ck["arch"]["depth"]) + 1)
    x = torch.zeros(1, C, 6 * m, 8 * m)
    # sizes are multiples of m (the predictor pads, as the network itself would): no padding branch
    h, w = m * torch.export.Dim("height_blocks", max=8192 // m), m * torch.export.Dim("width_blocks", max=8192 // m)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with torch.inference_mode(False), torch.no_grad():
        prog = torch.onnx.export(net, (x,), dynamo=True, opset_version=opset, input_names=["x"],
                                 output_names=["logits"], dynamic_shapes={"x": {2: h, 3: w}}, verbose=False)
    proto = prog.model_proto
    for k, v in (("sltwin_format", ONNX_FORMAT), ("sltwin_arch", json.dumps(ck["arch"])),
                 ("sltwin_meta", json.dumps(ck["meta"], default=str))):
        entry = proto.metadata_props.add()
        entry.key, entry.value = k, v
    with atomic_path(out) as tmp:                # the previous file stays until the checked model replaces it
        tmp.write_bytes(proto.SerializeToString())
        onnx.checker.check_model(str(tmp))
    return out
