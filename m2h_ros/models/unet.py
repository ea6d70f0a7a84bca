"""Building blocks of the separators: the U-Net of f^B / f^M and the acoustic-memory refiner f^R.

U-Net (Move2Hear supplementary): 5 convs k4 s2 p1 with BatchNorm + LeakyReLU(0.2); 5 transposed convs
k4 s2 p1 with BatchNorm + ReLU, each (after the first) fed the concatenation of the previous output
and the mirrored encoder feature; a final 1x1 conv. A 32x32 input goes 32->16->8->4->2->1 and back.
All weights Kaiming-normal (gain for the following nonlinearity), biases zero, BN affine = (1, 0).
"""

from __future__ import annotations

import torch
from torch import nn

from m2h_ros.errors import ConfigError

LEAKY_SLOPE = 0.2


def _down(in_channels: int, out_channels: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(in_channels, out_channels, kernel_size=4, stride=2, padding=1, bias=False),
        nn.BatchNorm2d(out_channels),
        nn.LeakyReLU(LEAKY_SLOPE, inplace=True),
    )


def _up(in_channels: int, out_channels: int) -> nn.Sequential:
    return nn.Sequential(
        nn.ConvTranspose2d(in_channels, out_channels, kernel_size=4, stride=2, padding=1, bias=False),
        nn.BatchNorm2d(out_channels),
        nn.ReLU(inplace=True),
    )


def init_weights(module: nn.Module, *, nonlinearity: str) -> None:
    for layer in module.modules():
        if isinstance(layer, (nn.Conv2d, nn.ConvTranspose2d)):
            if nonlinearity == "leaky_relu":
                nn.init.kaiming_normal_(layer.weight, a=LEAKY_SLOPE, nonlinearity="leaky_relu")
            else:
                nn.init.kaiming_normal_(layer.weight, nonlinearity="relu")
            if layer.bias is not None:
                nn.init.zeros_(layer.bias)
        elif isinstance(layer, nn.BatchNorm2d):
            nn.init.ones_(layer.weight)
            nn.init.zeros_(layer.bias)


class UNet(nn.Module):
    """(B, in_channels, H, W) -> (B, out_channels, H, W) raw scores (no output activation).

    ``channels`` are the five encoder widths (the paper: 64, 128, 256, 512, 512); H and W must be
    divisible by 32.
    """

    def __init__(self, in_channels: int, out_channels: int, channels: tuple[int, ...]) -> None:
        super().__init__()
        if len(channels) != 5:
            raise ConfigError(f"UNet needs 5 encoder widths, got {channels}")
        widths = (in_channels, *channels)
        self.encoder = nn.ModuleList(_down(widths[i], widths[i + 1]) for i in range(5))
        # Decoder level i mirrors encoder level 4 - i; all but the first also take that skip feature.
        decoder_in = [channels[4]] + [2 * channels[3 - i] for i in range(4)]
        decoder_out = [channels[3 - i] for i in range(4)] + [out_channels]
        self.decoder = nn.ModuleList(_up(i, o) for i, o in zip(decoder_in, decoder_out, strict=True))
        self.head = nn.Conv2d(out_channels, out_channels, kernel_size=1)
        init_weights(self.encoder, nonlinearity="leaky_relu")
        init_weights(self.decoder, nonlinearity="relu")
        init_weights(self.head, nonlinearity="relu")

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """(B, out_channels, H, W): the last decoder level's output, what the 1x1 head reads."""
        skips = []
        for layer in self.encoder:
            x = layer(x)
            skips.append(x)
        x = self.decoder[0](x)
        for layer, skip in zip(self.decoder[1:], reversed(skips[:-1]), strict=True):
            x = layer(torch.cat((x, skip), dim=1))
        return x

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.features(x))


class MemoryRefiner(nn.Module):
    """f^R: conv k3 s1 p1 -> BN -> ReLU -> conv k3 s1 p1 on [current, previous] (2C channels) -> C.

    The output is a *correction* added to the current estimate by the caller; the last conv is
    zero-initialised so an untrained refiner is the identity (refined = current) and training starts
    from the unrefined estimate instead of from noise.
    """

    def __init__(self, channels: int, hidden: int) -> None:
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv2d(2 * channels, hidden, kernel_size=3, padding=1, bias=False),
            nn.BatchNorm2d(hidden),
            nn.ReLU(inplace=True),
            nn.Conv2d(hidden, channels, kernel_size=3, padding=1, bias=False),
        )
        init_weights(self.body, nonlinearity="relu")
        nn.init.zeros_(self.body[-1].weight)

    def forward(self, current: torch.Tensor, previous: torch.Tensor) -> torch.Tensor:
        return self.body(torch.cat((current, previous), dim=1))
