"""The fringe-order network: a small U-Net with GroupNorm and a dilated bottleneck, run at half
resolution between a pixel-unshuffle and a pixel-shuffle.

Design: the errors to fix are coherent over whole surfaces (a biased low-frequency phase) as
well as single noisy pixels, so the receptive field must span an object (``depth`` poolings by 2
after a 2x pixel-unshuffle, and a bottleneck of dilated convolutions: about 250 px at the
defaults) while the output stays per pixel (skip connections; the pixel-unshuffle keeps every
input value, as 4 channels per 2x2 block, so nothing is averaged away, and a per-pixel 1x1
refinement sees the raw inputs beside the shuffled-back features). Running the U-Net on a quarter
of the pixels costs about half the arithmetic of a full-resolution one of the same receptive
field - what makes an hour of training on 2 CPU cores useful. GroupNorm instead of BatchNorm: the result of a sample does not
depend on the other samples of its batch, so one step of 2 processes x batch b equals one step
of 1 process x batch 2b (the distributed-training test), and training and inference behave the
same. Inputs of any size: they are padded (zeros = invalid) at the bottom and right to a multiple
of ``2**(depth + 1)`` and the output cropped back.

Options for a network that must run fast on a CPU (docs/speed.md, "A lighter network"):
``norm = "batch"`` (BatchNorm, folded into the convolutions at export: no frame-wide statistics,
so an output depends only on its receptive field, but a batch's samples are no longer
independent in training) or ``"none"``, ``stem = "strided"`` (the pixel (un)shuffle folded into a
stride-2 convolution and a transposed one: the same function class without the data movement),
``conv = "separable"``.

SYNOPSIS

    >>> import torch
    >>> from unwrap.learned.network import FringeUNet
    >>> net = FringeUNet(7, 5, width=8, depth=2)
    >>> tuple(net(torch.zeros(1, 7, 30, 41)).shape)
    (1, 5, 30, 41)
"""
from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F


def _groups(channels: int) -> int:
    for g in (8, 4, 2):
        if channels % g == 0:
            return g
    return 1


#: Convolution kinds of :class:`ConvBlock` (``[model] conv``): "full" 3x3 convolutions (the
#: shipped model), or "separable": a depthwise 3x3 then a pointwise 1x1 (same receptive field,
#: ~c_out/9 + 1 times fewer multiply-adds per layer; docs/speed.md measures what it buys).
CONV_KINDS = ("full", "separable")


#: Normalisations of :class:`ConvBlock` (``[model] norm``): "group" (GroupNorm over the whole
#: frame: the shipped model; a sample's result is independent of its batch), "batch" (BatchNorm:
#: batch statistics in training, fixed running statistics at inference, where it folds into the
#: preceding convolution - no frame-wide operation remains, so every output depends only on its
#: receptive field and a frame can be tiled exactly), or "none" (convolutions with a bias).
NORM_KINDS = ("group", "batch", "none")

#: How the U-Net gets to and from half resolution (``[model] stem``): "shuffle" (the shipped
#: model: a pixel-unshuffle before the first 3x3 convolution, a 1x1 head and a pixel-shuffle
#: after the last, the shuffled features concatenated with the raw inputs for the refinement) or
#: "strided": the same function class without the data movement - the unshuffle and the first
#: 3x3 convolution as one 6x6 convolution of stride 2 (it sees the same 6x6 input pixels per
#: output), the head and the pixel-shuffle as one 2x2 transposed convolution of stride 2, and the
#: refinement's first 1x1 convolution of the concatenation as the sum of a 1x1 convolution of the
#: raw inputs and that transposed convolution (its bias per channel, not per sub-pixel). The 6x6
#: convolution is a full one whatever ``conv`` says (with "separable", the first block's first
#: convolution is the only full one).
STEM_KINDS = ("shuffle", "strided")


def _conv3(c_in: int, c_out: int, dilation: int, conv: str, bias: bool = False) -> nn.Module:
    if conv == "separable":
        return nn.Sequential(nn.Conv2d(c_in, c_in, 3, padding=dilation, dilation=dilation, groups=c_in, bias=False),
                             nn.Conv2d(c_in, c_out, 1, bias=bias))
    return nn.Conv2d(c_in, c_out, 3, padding=dilation, dilation=dilation, bias=bias)


def _norm(c: int, norm: str) -> nn.Module:
    if norm == "batch":
        return nn.BatchNorm2d(c)
    if norm == "none":
        return nn.Identity()
    return nn.GroupNorm(_groups(c), c)


class ConvBlock(nn.Sequential):
    """Two 3x3 convolutions, each followed by a normalisation and SiLU (``dilation`` on both;
    ``conv``: one of :data:`CONV_KINDS`; ``norm``: one of :data:`NORM_KINDS`, "none" gives the
    convolutions a bias instead)."""

    def __init__(self, c_in: int, c_out: int, dilation: int = 1, conv: str = "full", norm: str = "group"):
        bias = norm == "none"
        super().__init__(
            _conv3(c_in, c_out, dilation, conv, bias), _norm(c_out, norm), nn.SiLU(inplace=True),
            _conv3(c_out, c_out, dilation, conv, bias), _norm(c_out, norm), nn.SiLU(inplace=True))


class FringeUNet(nn.Module):
    """U-Net mapping (B, in_channels, H, W) -> (B, out_channels, H, W).

    ARGUMENTS: in_channels, out_channels; width = channels of the first level (doubled per level,
    at most ``max_width``); depth = number of 2x poolings after the 2x pixel-unshuffle; dilations
    of the bottleneck blocks; conv: the blocks' convolutions (:data:`CONV_KINDS`); norm: their
    normalisation (:data:`NORM_KINDS`); stem: to and from half resolution (:data:`STEM_KINDS`).
    """

    def __init__(self, in_channels: int, out_channels: int, width: int = 16, depth: int = 3,
                 max_width: int = 64, dilations=(2, 4), conv: str = "full", norm: str = "group",
                 stem: str = "shuffle"):
        super().__init__()
        if conv not in CONV_KINDS:
            raise ValueError(f"conv {conv!r}: expected one of {CONV_KINDS}")
        if norm not in NORM_KINDS:
            raise ValueError(f"norm {norm!r}: expected one of {NORM_KINDS}")
        if stem not in STEM_KINDS:
            raise ValueError(f"stem {stem!r}: expected one of {STEM_KINDS}")
        self.stem = stem
        self.depth = int(depth)
        w = int(width)
        chans = [min(w * 2 ** i, int(max_width)) for i in range(self.depth + 1)]
        kw = dict(conv=conv, norm=norm)
        self.enc = nn.ModuleList([ConvBlock(4 * in_channels, chans[0], **kw)] +
                                 [ConvBlock(chans[i - 1], chans[i], **kw) for i in range(1, self.depth + 1)])
        self.mid = nn.Sequential(*[ConvBlock(chans[-1], chans[-1], d, **kw) for d in dilations])
        self.dec = nn.ModuleList([ConvBlock(chans[i + 1] + chans[i], chans[i], **kw) for i in range(self.depth)])
        if stem == "strided":
            self.enc[0][0] = nn.Conv2d(in_channels, chans[0], 6, stride=2, padding=2, bias=norm == "none")
            self.head = nn.ConvTranspose2d(chans[0], w, 2, stride=2)
            self.raw = nn.Conv2d(in_channels, w, 1, bias=False)
            self.refine = nn.Sequential(nn.SiLU(inplace=True), nn.Conv2d(w, out_channels, 1))
        else:
            self.head = nn.Conv2d(chans[0], 4 * w, 1)
            self.refine = nn.Sequential(nn.Conv2d(in_channels + w, w, 1), nn.SiLU(inplace=True),
                                        nn.Conv2d(w, out_channels, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        H, W = x.shape[-2:]
        m = 2 ** (self.depth + 1)
        ph, pw = (-H) % m, (-W) % m
        if ph or pw:
            x = F.pad(x, (0, pw, 0, ph))
        full = x
        if self.stem == "shuffle":
            x = F.pixel_unshuffle(x, 2)
        skips = []
        for i, block in enumerate(self.enc):
            x = block(x if i == 0 else F.avg_pool2d(x, 2))
            skips.append(x)
        x = self.mid(x)
        for i in reversed(range(self.depth)):
            x = F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)
            x = self.dec[i](torch.cat([x, skips[i]], dim=1))
        if self.stem == "strided":
            return self.refine(self.head(x) + self.raw(full))[..., :H, :W]
        y = F.pixel_shuffle(self.head(x), 2)
        return self.refine(torch.cat([full, y], dim=1))[..., :H, :W]


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def count_macs(model: nn.Module, in_channels: int, size) -> int:
    """Multiply-adds of the convolutions of one forward of a (1, in_channels, H, W) input, ``size``
    = (H, W) (normalisation, SiLU, pooling and resampling not counted: a few per activation); the
    model is left as it was (mode, weights and BatchNorm statistics)."""
    total = []

    def hook(mod, inp, out):
        k = mod.kernel_size[0] * mod.kernel_size[1]
        if isinstance(mod, nn.ConvTranspose2d):    # each input pixel scatters k taps into each output channel
            total.append(inp[0].numel() * (mod.out_channels // mod.groups) * k)
        else:
            total.append(out.numel() * (mod.in_channels // mod.groups) * k)

    hs = [m.register_forward_hook(hook) for m in model.modules() if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d))]
    training = model.training
    try:
        with torch.inference_mode():
            model.eval()                           # a training BatchNorm would update its running statistics
            model(torch.zeros(1, in_channels, *size))
    finally:
        model.train(training)
        for h in hs:
            h.remove()
    return int(sum(total))
