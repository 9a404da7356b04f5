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
same. Inputs of any size: they are padded (zeros = invalid) to a multiple of ``2**depth`` and the
output cropped back.

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


def _conv3(c_in: int, c_out: int, dilation: int, conv: str) -> nn.Module:
    if conv == "separable":
        return nn.Sequential(nn.Conv2d(c_in, c_in, 3, padding=dilation, dilation=dilation, groups=c_in, bias=False),
                             nn.Conv2d(c_in, c_out, 1, bias=False))
    return nn.Conv2d(c_in, c_out, 3, padding=dilation, dilation=dilation, bias=False)


class ConvBlock(nn.Sequential):
    """Two 3x3 convolutions, each followed by GroupNorm and SiLU (``dilation`` on both; ``conv``:
    one of :data:`CONV_KINDS`)."""

    def __init__(self, c_in: int, c_out: int, dilation: int = 1, conv: str = "full"):
        super().__init__(
            _conv3(c_in, c_out, dilation, conv),
            nn.GroupNorm(_groups(c_out), c_out), nn.SiLU(inplace=True),
            _conv3(c_out, c_out, dilation, conv),
            nn.GroupNorm(_groups(c_out), c_out), nn.SiLU(inplace=True))


class FringeUNet(nn.Module):
    """U-Net mapping (B, in_channels, H, W) -> (B, out_channels, H, W).

    ARGUMENTS: in_channels, out_channels; width = channels of the first level (doubled per level,
    at most ``max_width``); depth = number of 2x poolings after the 2x pixel-unshuffle; dilations
    of the bottleneck blocks; conv: the blocks' convolutions (:data:`CONV_KINDS`).
    """

    def __init__(self, in_channels: int, out_channels: int, width: int = 16, depth: int = 3,
                 max_width: int = 64, dilations=(2, 4), conv: str = "full"):
        super().__init__()
        if conv not in CONV_KINDS:
            raise ValueError(f"conv {conv!r}: expected one of {CONV_KINDS}")
        self.depth = int(depth)
        w = int(width)
        chans = [min(w * 2 ** i, int(max_width)) for i in range(self.depth + 1)]
        self.enc = nn.ModuleList([ConvBlock(4 * in_channels, chans[0], conv=conv)] +
                                 [ConvBlock(chans[i - 1], chans[i], conv=conv) for i in range(1, self.depth + 1)])
        self.mid = nn.Sequential(*[ConvBlock(chans[-1], chans[-1], d, conv) for d in dilations])
        self.dec = nn.ModuleList([ConvBlock(chans[i + 1] + chans[i], chans[i], conv=conv) for i in range(self.depth)])
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
        x = F.pixel_unshuffle(x, 2)
        skips = []
        for i, block in enumerate(self.enc):
            x = block(x if i == 0 else F.avg_pool2d(x, 2))
            skips.append(x)
        x = self.mid(x)
        for i in reversed(range(self.depth)):
            x = F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)
            x = self.dec[i](torch.cat([x, skips[i]], dim=1))
        y = F.pixel_shuffle(self.head(x), 2)
        return self.refine(torch.cat([full, y], dim=1))[..., :H, :W]


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def count_macs(model: nn.Module, in_channels: int, size) -> int:
    """Multiply-adds of the convolutions of one forward of a (1, in_channels, H, W) input, ``size``
    = (H, W) (GroupNorm, SiLU, pooling and resampling not counted: a few per activation)."""
    total = []

    def hook(mod, inp, out):
        k = mod.kernel_size[0] * mod.kernel_size[1]
        total.append(out.numel() * (mod.in_channels // mod.groups) * k)

    hs = [m.register_forward_hook(hook) for m in model.modules() if isinstance(m, nn.Conv2d)]
    try:
        with torch.inference_mode():
            model(torch.zeros(1, in_channels, *size))
    finally:
        for h in hs:
            h.remove()
    return int(sum(total))
