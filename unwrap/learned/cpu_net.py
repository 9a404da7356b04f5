"""The network as the CPU runs it at inference: BatchNorm folded into the convolutions, the
weights in channels-last memory format (a private copy: the caller's network is left as it was).

Both change only the float rounding, never the function: a folded convolution computes
``(w * s) (*) x + (b - mu) * s + beta`` (``s = gamma / sqrt(var + eps)``) instead of the
convolution then the normalisation; channels-last runs oneDNN's convolutions on (N, H, W, C)
blocks instead of reordering each layer's input (for this 0.1-0.5 M-parameter U-Net the reorders
cost more than the convolutions; docs/speed.md, "The learned path on 2 CPU cores"). The logits
move by ~1e-5, so a pixel's order can change only where two classes' logits tie within that
(counted on the real captures by ``python -m bench.learned_gpu --frames FRAMES.npz``, its
"cpu fp32 channels-last folded" rows).

Channels-last pays most when the input already lies in that layout (the conversion of an NCHW
input costs ~10 ms at 640 x 480): :func:`unwrap.learned.fast_features.make_inputs` writes the
features in (H, W, C) order for a predictor whose ``input_layout`` is "nhwc".

SYNOPSIS

    >>> import torch
    >>> from unwrap.learned.network import FringeUNet
    >>> from unwrap.learned.cpu_net import prepare_for_cpu
    >>> net = FringeUNet(7, 5, width=8, depth=2, norm="batch", stem="strided").eval()
    >>> fast = prepare_for_cpu(net, channels_last=True, fold=True)
    >>> x = torch.randn(1, 7, 32, 48)
    >>> with torch.inference_mode():
    ...     bool(torch.allclose(fast(x.contiguous(memory_format=torch.channels_last)), net(x), atol=1e-4))
    True
"""
from __future__ import annotations

import copy

import torch
from torch import nn


def fold_batchnorm(net: nn.Module) -> int:
    """Fold every BatchNorm2d that directly follows a Conv2d in an ``nn.Sequential`` of ``net``
    (in place; eval-mode statistics) into that convolution, the BatchNorm replaced by an
    identity. Returns the number folded. A network with GroupNorm or no norm is left as it is."""
    folded = 0
    for mod in net.modules():
        if not isinstance(mod, nn.Sequential):
            continue
        names = list(mod._modules)
        for a, b in zip(names[:-1], names[1:]):
            conv, bn = mod._modules[a], mod._modules[b]
            if isinstance(conv, nn.Conv2d) and isinstance(bn, nn.BatchNorm2d) and bn.track_running_stats:
                mod._modules[a] = torch.nn.utils.fusion.fuse_conv_bn_eval(conv.eval(), bn.eval())
                mod._modules[b] = nn.Identity()
                folded += 1
    return folded


def prepare_for_cpu(net: nn.Module, *, channels_last: bool, fold: bool) -> nn.Module:
    """An eval-mode copy of ``net`` with BatchNorm folded (``fold``) and its weights channels-last
    (``channels_last``); ``net`` itself is not modified."""
    fast = copy.deepcopy(net).eval()
    if fold:
        fold_batchnorm(fast)
    if channels_last:
        fast = fast.to(memory_format=torch.channels_last)
    return fast


class CpuCopy:
    """``prepare_for_cpu(net, ...)`` kept in step with ``net``: called like a module, it runs the
    private copy, made again first where ``net``'s parameters or buffers changed since it was made
    (fine-tuned in place by an optimiser, ``load_state_dict``, a tensor replaced), and runs ``net``
    itself while ``net`` is in train mode (folding takes the running statistics of now).

    A change is seen through each parameter's and buffer's identity, storage address and version
    counter (torch bumps it on every in-place operation): ~0.05 ms a call for the shipped model's
    132 tensors, against a forward of ~40 ms. Not seen: writes that bypass the counter (in place
    through ``tensor.data`` or a numpy view of a tensor) and submodules replaced by new ones; call
    :meth:`refresh` after those.

    >>> from unwrap.learned.network import FringeUNet
    >>> net = FringeUNet(7, 5, width=8, depth=2, norm="batch", stem="strided").eval()
    >>> fast = CpuCopy(net, channels_last=False, fold=True)
    >>> x = torch.randn(1, 7, 32, 48)
    >>> with torch.no_grad():
    ...     _ = net.enc[0][0].weight.mul_(2.0)           # fine-tuned in place
    >>> with torch.inference_mode():
    ...     bool(torch.allclose(fast(x), net(x), atol=1e-4)), fast.copies
    (True, 2)
    """

    def __init__(self, net: nn.Module, *, channels_last: bool, fold: bool):
        self.net, self.channels_last, self.fold = net, channels_last, fold
        self.copies = 0          # copies made (1 + the refreshes a change caused)
        self.refresh()

    def _state(self) -> list:
        """(identity, storage address, version) of every parameter and buffer of the modules ``net`` had."""
        out = []
        for d, name in self._slots:
            t = d.get(name)
            if t is None:
                out.append(None)
                continue
            try:
                version = t._version
            except RuntimeError:          # an inference tensor: no version counter, no in-place change outside it
                version = -1
            out.append((id(t), t.data_ptr(), version))
        return out

    def refresh(self) -> None:
        """Make the private copy again from ``net`` as it is now."""
        self._slots = [(d, name) for m in self.net.modules() for d in (m._parameters, m._buffers) for name in d]
        self._seen = self._state()
        self.copy = prepare_for_cpu(self.net, channels_last=self.channels_last, fold=self.fold)
        self.copies += 1

    def __call__(self, x):
        if self.net.training:
            return self.net(x)
        if self._state() != self._seen:
            self.refresh()
        return self.copy(x)
