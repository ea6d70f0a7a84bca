"""Fast inference copies of a trained :class:`~m2h_ros.models.separator.Separator`.

:func:`fuse_for_inference` returns a copy in which every convolution, the BatchNorm after it and the
activation after that are one :class:`FusedConv`: the BatchNorm's running statistics are folded into
the convolution's weight and bias (exact up to float rounding, since eval-mode BatchNorm is an affine
map per channel), and on CPU the convolution runs through oneDNN with its weight reordered once
("prepacked") and the activation applied inside the same kernel.

Why: at batch 1 a step is bound by per-call overhead, not arithmetic. A plain ``F.conv2d`` on CPU
reorders the weight into oneDNN's blocked layout on *every* call; for the paper preset's 512-channel
bottleneck that is a 16 MB copy per layer and call, which costs far more than the convolution itself,
and for the compact preset each call pays tens of microseconds for it. Prepacking removes that.
``scripts/bench/separator.py`` measures the difference; docs/design/separator.md has the table.

The copy is for inference only: it has no BatchNorm left to train, its parameters do not require
gradients, and it must not be saved as a checkpoint (save the original). Its outputs equal the
original's in eval mode to float tolerance (test/models/test_separator_inference.py checks it on random
weights and on the shipped checkpoint).

The prepacked path uses ``torch.ops.mkldnn`` (the kernels torch's inductor uses for frozen CPU
models; torch is pinned). Without oneDNN, or off the CPU, the folded weights run through the plain
``F.conv2d`` / ``F.conv_transpose2d`` instead; the numbers are the same.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import TypeVar

import torch
import torch.nn.functional as F
from torch import nn

from m2h_ros.errors import ConfigError

Model = TypeVar("Model", bound=nn.Module)

_CONVS = (nn.Conv2d, nn.ConvTranspose2d)
_ACTIVATIONS = (nn.ReLU, nn.LeakyReLU)


def _folded(conv: nn.Conv2d | nn.ConvTranspose2d, norm: nn.BatchNorm2d | None) -> tuple[torch.Tensor, torch.Tensor]:
    """(weight, bias) of ``norm(conv(x))`` as one convolution; eval-mode BatchNorm only."""
    weight = conv.weight.detach()
    bias = conv.bias.detach() if conv.bias is not None else weight.new_zeros(conv.out_channels)
    if norm is None:
        return weight.clone(), bias.clone()
    if norm.running_mean is None or norm.running_var is None or not norm.affine:
        raise ConfigError("fuse_for_inference needs BatchNorm layers with running statistics and affine weights")
    scale = norm.weight.detach() / torch.sqrt(norm.running_var + norm.eps)
    shift = norm.bias.detach() - norm.running_mean * scale
    # Output channels are dim 0 of a Conv2d weight (out, in, kh, kw), dim 1 of a ConvTranspose2d's.
    per_channel = (1, -1, 1, 1) if isinstance(conv, nn.ConvTranspose2d) else (-1, 1, 1, 1)
    return weight * scale.reshape(per_channel), bias * scale + shift


class FusedConv(nn.Module):
    """conv -> (folded BatchNorm) -> (ReLU | LeakyReLU) as one inference-only layer.

    Only what the separator uses: groups 1, dilation 1, no output padding.
    """

    def __init__(self, conv: nn.Conv2d | nn.ConvTranspose2d, norm: nn.BatchNorm2d | None = None,
                 activation: nn.ReLU | nn.LeakyReLU | None = None) -> None:
        super().__init__()
        if conv.groups != 1 or any(d != 1 for d in conv.dilation) or any(getattr(conv, "output_padding", (0, 0))):
            raise ConfigError(f"FusedConv supports groups=1, dilation=1, no output padding; got {conv}")
        weight, bias = _folded(conv, norm)
        self.weight = nn.Parameter(weight, requires_grad=False)
        self.bias = nn.Parameter(bias, requires_grad=False)
        self.transposed = isinstance(conv, nn.ConvTranspose2d)
        self.stride, self.padding = list(conv.stride), list(conv.padding)
        if activation is None:
            self.activation, self.scalars = "none", []
        elif isinstance(activation, nn.LeakyReLU):
            self.activation, self.scalars = "leaky_relu", [float(activation.negative_slope)]
        else:
            self.activation, self.scalars = "relu", []
        # One kernel per input (C, H, W), dtype, device kind and torch thread count, made on first use.
        # On CPU it holds the weight reordered for oneDNN, whose layout depends on the input's spatial
        # size and on the thread count (a weight packed under 2 threads made 1-thread steps 2.5x
        # slower: oneDNN reordered it again on every call), not on the batch (a weight packed for
        # batch 1 serves batch 32). A bound closure keeps the per-call Python work small (it is a
        # visible part of a 50-100 us layer).
        self._kernels: dict[tuple, Callable[[torch.Tensor], torch.Tensor]] = {}

    def __getstate__(self) -> dict:
        # oneDNN's packed weights can be neither copied nor pickled; a copy packs again on first use.
        return {**self.__dict__, "_kernels": {}}

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        key = (x.shape[1:], x.dtype, x.is_cpu, torch.get_num_threads())
        kernel = self._kernels.get(key)
        if kernel is None:
            kernel = self._kernels[key] = self._kernel(x)
        return kernel(x)

    def _kernel(self, x: torch.Tensor) -> Callable[[torch.Tensor], torch.Tensor]:
        if not (x.is_cpu and x.dtype == torch.float32 and torch.backends.mkldnn.is_available()):
            return self._plain
        bias, padding, stride, activation, scalars = self.bias, self.padding, self.stride, self.activation, self.scalars
        size = [1, *x.shape[1:]]
        mkldnn = torch.ops.mkldnn
        if self.transposed:
            weight = mkldnn._reorder_convolution_transpose_weight(self.weight, padding, [0, 0], stride, [1, 1], 1, size)
            return lambda x: mkldnn._convolution_transpose_pointwise(
                x, weight, bias, padding, [0, 0], stride, [1, 1], 1, activation, scalars, "")
        weight = mkldnn._reorder_convolution_weight(self.weight, padding, stride, [1, 1], 1, size)
        return lambda x: mkldnn._convolution_pointwise(
            x, weight, bias, padding, stride, [1, 1], 1, activation, scalars, "")

    def _plain(self, x: torch.Tensor) -> torch.Tensor:
        conv = F.conv_transpose2d if self.transposed else F.conv2d
        y = conv(x, self.weight, self.bias, stride=self.stride, padding=self.padding)
        if self.activation == "relu":
            return F.relu(y)
        if self.activation == "leaky_relu":
            return F.leaky_relu(y, self.scalars[0])
        return y

    def extra_repr(self) -> str:
        kind = "transposed" if self.transposed else "conv"
        return f"{kind} {tuple(self.weight.shape)}, stride={self.stride}, padding={self.padding}, {self.activation}"


def _fuse_sequential(block: nn.Sequential) -> nn.Module:
    """The fused layers of ``block``; a lone layer stands alone (one module call fewer per layer)."""
    layers, fused, i = list(block), [], 0
    while i < len(layers):
        layer = layers[i]
        if isinstance(layer, nn.BatchNorm2d):
            raise ConfigError("fuse_for_inference: a BatchNorm2d that does not follow a convolution cannot be folded")
        if not isinstance(layer, _CONVS):
            fused.append(_fuse_children(layer))
            i += 1
            continue
        norm = layers[i + 1] if i + 1 < len(layers) and isinstance(layers[i + 1], nn.BatchNorm2d) else None
        i += 1 + (norm is not None)
        activation = layers[i] if i < len(layers) and isinstance(layers[i], _ACTIVATIONS) else None
        i += activation is not None
        fused.append(FusedConv(layer, norm, activation))
    return fused[0] if len(fused) == 1 else nn.Sequential(*fused)


def _fuse_children(module: nn.Module) -> nn.Module:
    """Replace, in place, every conv (with the BatchNorm / activation after it in a Sequential)."""
    for name, child in module.named_children():
        if isinstance(child, nn.Sequential):
            setattr(module, name, _fuse_sequential(child))
        elif isinstance(child, _CONVS):
            setattr(module, name, FusedConv(child))
        elif isinstance(child, nn.BatchNorm2d):
            raise ConfigError(f"fuse_for_inference: BatchNorm2d {name!r} outside a Sequential cannot be folded")
        else:
            _fuse_children(child)
    return module


def fuse_for_inference(separator: Model) -> Model:
    """An inference copy of ``separator`` (or of any module built from the same layers, such as the
    listener): BatchNorm folded into the convolutions, activations fused, CPU weights prepacked for
    oneDNN; the original is left untouched.

    Same class, same call signature and outputs (to float tolerance) as ``separator.eval()``; run it
    under ``torch.inference_mode()`` (``separate_clip`` does). Do not train it or save it.
    """
    fused = copy.deepcopy(separator).eval()
    _fuse_children(fused)
    return fused.requires_grad_(False)
