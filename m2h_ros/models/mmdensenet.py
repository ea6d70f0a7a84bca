"""An MMDenseNet-style backbone for f^B / f^M (Takahashi & Mitsufuji 2017, multi-scale multi-band
DenseNets), in place of the U-Net and with its inputs and outputs, sized for the CPU.

The input is the separators' sliced layout: ``groups`` spectrogram channels (the ears) of
``n_slices`` frequency slices each (channel ``g * S + s``), then ``extra`` planes every net sees (the
class plane). Frequency runs over the slices, so a band is a range of slices: :data:`BAND_EDGES`
cuts the axis at 1/4 and 1/2 (with the paper's STFT at 16 kHz: 0-2, 2-4 and 4-8 kHz).

* One :class:`MDenseNet` per band, on that band's slices of every group plus the extra planes, and
  one on the whole input (MMDenseNet's full-band net).
* MDenseNet: a dense-block encoder/decoder. A stem conv; per level a dense block (each layer a 3x3
  conv fed the concatenation of the block input and every earlier layer's output) and a transition
  (1x1 conv halving the width, 2x2 average pool); a bottleneck block; per level back up a 2x2
  transposed conv, the concatenation with the skip of that level and a dense block; a 1x1 conv to
  the net's output features.
* The four nets' features are concatenated along channels and fused by a final dense block and a
  1x1 conv to the raw scores. (In the sliced layout frequency lies in the channels, so this channel
  concatenation is the paper's concatenation of the band outputs along frequency, plus the full band.)

Differences from the paper, on purpose: conv -> BN -> ReLU (post-activation) instead of BN -> ReLU ->
conv, so the inference copy folds every BatchNorm into its conv (``models.inference``); the same
growth rate in every band (the paper gives the low band more); 3x3 convs over the 32 bins of a slice
x the frames. Weights as the U-Net's (Kaiming-normal, zero biases, BN affine = (1, 0)).
"""

from __future__ import annotations

import torch
from torch import nn

from m2h_ros.errors import AudioError, ConfigError
from m2h_ros.models.unet import init_weights

BAND_EDGES = (0.0, 0.25, 0.5, 1.0)  # fractions of the frequency axis: low, mid, high band
DENSE_LAYERS = 3  # layers per dense block
LEVELS = 2  # down-samplings inside an MDenseNet after its stride-2 stem: 32 x 32 -> 16 -> 8 -> 4 (the bottleneck)
DOWNSAMPLING = 2 ** (LEVELS + 1)  # plane sides must be multiples of this


def _conv(in_channels: int, out_channels: int, kernel_size: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(in_channels, out_channels, kernel_size, padding=kernel_size // 2, bias=False),
        nn.BatchNorm2d(out_channels),
        nn.ReLU(inplace=True),
    )


class DenseBlock(nn.Module):
    """``layers`` conv3x3-BN-ReLU of ``growth`` channels, each fed everything before it; the output is
    the input and every layer's output concatenated (``out_channels`` = in + layers x growth)."""

    def __init__(self, in_channels: int, growth: int, layers: int = DENSE_LAYERS) -> None:
        super().__init__()
        self.layers = nn.ModuleList(_conv(in_channels + i * growth, growth, 3) for i in range(layers))
        self.out_channels = in_channels + layers * growth

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        features = [x]
        for layer in self.layers:
            features.append(layer(torch.cat(features, dim=1)))
        return torch.cat(features, dim=1)


class MDenseNet(nn.Module):
    """One band's dense encoder/decoder: (B, in_channels, H, W) -> (B, out_channels, H, W) features
    (after a ReLU); H and W multiples of :data:`DOWNSAMPLING`."""

    def __init__(self, in_channels: int, out_channels: int, growth: int) -> None:
        super().__init__()
        width = 2 * growth
        # k4 s2 like the U-Net's first layer: the dense blocks run at half resolution, 4x cheaper.
        self.stem = nn.Sequential(nn.Conv2d(in_channels, width, 4, stride=2, padding=1, bias=False),
                                  nn.BatchNorm2d(width), nn.ReLU(inplace=True))
        self.encoder, self.transitions, skips = nn.ModuleList(), nn.ModuleList(), []
        for _ in range(LEVELS):
            block = DenseBlock(width, growth)
            self.encoder.append(block)
            skips.append(block.out_channels)
            width = block.out_channels // 2
            self.transitions.append(nn.Sequential(*_conv(block.out_channels, width, 1), nn.AvgPool2d(2)))
        self.bottleneck = DenseBlock(width, growth)
        width = self.bottleneck.out_channels
        self.ups, self.decoder = nn.ModuleList(), nn.ModuleList()
        for skip in reversed(skips):
            self.ups.append(nn.Sequential(nn.ConvTranspose2d(width, width // 2, 2, stride=2, bias=False),
                                          nn.BatchNorm2d(width // 2), nn.ReLU(inplace=True)))
            block = DenseBlock(width // 2 + skip, growth)
            self.decoder.append(block)
            width = block.out_channels
        self.head = _conv(width, out_channels, 1)
        init_weights(self, nonlinearity="relu")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.stem(x)
        skips = []
        for block, transition in zip(self.encoder, self.transitions, strict=True):
            x = block(x)
            skips.append(x)
            x = transition(x)
        x = self.bottleneck(x)
        for up, block, skip in zip(self.ups, self.decoder, reversed(skips), strict=True):
            x = block(torch.cat((up(x), skip), dim=1))
        return self.head(x)


def band_slices(n_slices: int) -> list[tuple[int, int]]:
    """The [first, stop) slice range of each band of :data:`BAND_EDGES` (ConfigError if one is empty)."""
    edges = [round(edge * n_slices) for edge in BAND_EDGES]
    bands = list(zip(edges[:-1], edges[1:]))
    if any(stop <= first for first, stop in bands):
        raise ConfigError(f"MMDenseNet needs at least one slice per band; {n_slices} slices give bands {bands}")
    return bands


class MMDenseNet(nn.Module):
    """(B, groups * n_slices + extra, H, W) -> (B, out_channels, H, W) raw scores (no output
    activation), as :class:`~m2h_ros.models.unet.UNet`; ``growth`` sets every net's width."""

    def __init__(self, out_channels: int, *, groups: int, n_slices: int, extra: int, growth: int) -> None:
        super().__init__()
        if min(groups, n_slices, growth) < 1 or extra < 0:
            raise ConfigError(f"MMDenseNet needs positive groups, n_slices and growth, got {groups}, {n_slices}, "
                              f"{growth} (extra {extra})")
        self.groups, self.n_slices, self.extra = groups, n_slices, extra
        self.bands = band_slices(n_slices)
        features = 2 * growth
        self.band_nets = nn.ModuleList(MDenseNet(groups * (stop - first) + extra, features, growth)
                                       for first, stop in self.bands)
        self.full_net = MDenseNet(groups * n_slices + extra, features, growth)
        self.fusion = DenseBlock(features * (len(self.bands) + 1), growth)
        # Back to full resolution as the U-Net's last level: transposed conv k4 s2 + BN + ReLU, 1x1 conv.
        self.up = nn.Sequential(nn.ConvTranspose2d(self.fusion.out_channels, out_channels, 4, stride=2, padding=1,
                                                   bias=False), nn.BatchNorm2d(out_channels), nn.ReLU(inplace=True))
        self.head = nn.Conv2d(out_channels, out_channels, kernel_size=1)
        init_weights(self, nonlinearity="relu")

    def _band_input(self, x: torch.Tensor, first: int, stop: int) -> torch.Tensor:
        spans = [x[:, g * self.n_slices + first:g * self.n_slices + stop] for g in range(self.groups)]
        return torch.cat((*spans, x[:, self.groups * self.n_slices:]), dim=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        expected = self.groups * self.n_slices + self.extra
        if x.shape[1] != expected:
            raise AudioError(f"MMDenseNet expects {expected} input channels, got {x.shape[1]}")
        features = [net(self._band_input(x, first, stop)) for net, (first, stop) in zip(self.band_nets, self.bands,
                                                                                         strict=True)]
        features.append(self.full_net(x))
        return self.head(self.up(self.fusion(torch.cat(features, dim=1))))
