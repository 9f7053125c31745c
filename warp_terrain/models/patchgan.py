"""pix2pix's PatchGAN discriminator, conditioned on the input.

It sees `cat([condition, image], dim=1)` and returns one logit per overlapping patch (no
sigmoid: the loss applies it). With `n_layers` = 3 each logit sees 70x70 input pixels (the 70x70
PatchGAN); a 121x121 input gives a 13x13 logit map.
"""

from __future__ import annotations

import torch
from torch import nn

from .layers import conv_bias, init_weights, make_norm


class PatchDiscriminator(nn.Module):
    """(B, in_channels + out_channels, H, W) -> (B, 1, h, w) logits.

    `in_channels` counts the condition's channels and `out_channels` the image's, so the
    constructor mirrors the generator's; the net itself takes the concatenated pair.
    """

    def __init__(
        self,
        in_channels: int = 1,
        out_channels: int = 1,
        ndf: int = 64,
        n_layers: int = 3,
        norm: str = "batch",
    ):
        super().__init__()
        if n_layers < 1:
            raise ValueError(f"n_layers must be >= 1, got {n_layers}")
        bias = conv_bias(norm)
        layers: list[nn.Module] = [
            nn.Conv2d(in_channels + out_channels, ndf, 4, 2, 1),
            nn.LeakyReLU(0.2),
        ]
        mult = 1
        for n in range(1, n_layers):  # stride-2 layers, filters doubling up to 8 * ndf
            prev, mult = mult, min(2**n, 8)
            layers += [
                nn.Conv2d(ndf * prev, ndf * mult, 4, 2, 1, bias=bias),
                make_norm(norm, ndf * mult),
                nn.LeakyReLU(0.2),
            ]
        prev, mult = mult, min(2**n_layers, 8)
        layers += [
            nn.Conv2d(ndf * prev, ndf * mult, 4, 1, 1, bias=bias),
            make_norm(norm, ndf * mult),
            nn.LeakyReLU(0.2),
            nn.Conv2d(ndf * mult, 1, 4, 1, 1),  # one logit per patch
        ]
        self.model = nn.Sequential(*layers)
        init_weights(self)

    def forward(self, pair: torch.Tensor) -> torch.Tensor:
        return self.model(pair)
