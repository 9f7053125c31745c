"""A conventional U-Net: pix2pix's `UnetGenerator`, made size-agnostic and unbounded.

Every level is a kernel-4 stride-2 conv down and a kernel-4 stride-2 transposed conv up, with
the level's input concatenated to its output (pix2pix's recursive `UnetSkipConnectionBlock`).
Filters ngf * 1, 2, 4, 8, 8, ... (capped at 8 * ngf); dropout on the ngf*8 levels between the
fourth and the innermost, as pix2pix (depth 7 -> two dropout levels).

Differences from pix2pix:
- the input is replicate-padded to a multiple of 2**depth and the output cropped back, so any
  size works (121 -> 128 -> 121 at the default depth 7, whose bottleneck is 1x1);
- no final tanh: the output is a height in metres, not an image in [-1, 1];
- ``refine > 0`` adds a full-resolution head (:class:`RefineHead`): pix2pix's outermost level
  makes its output with one stride-2 transposed convolution from half-resolution features, so
  no layer sees single cells; the head takes that level's features and the input itself through
  ``refine`` 3x3 convolutions at full resolution, so a correction can be as sharp as the scan.
"""

from __future__ import annotations

import torch
from torch import nn

from .layers import conv_bias, init_weights, make_norm, match_size


class UNetLevel(nn.Module):
    """One level: down -> (inner levels) -> up; non-outermost levels return cat([x, up])."""

    def __init__(
        self,
        outer_nc: int,
        inner_nc: int,
        input_nc: int | None = None,
        submodule: nn.Module | None = None,
        outermost: bool = False,
        innermost: bool = False,
        norm: str = "batch",
        dropout: float = 0.0,
    ):
        super().__init__()
        self.outermost = outermost
        input_nc = outer_nc if input_nc is None else input_nc
        bias = conv_bias(norm)
        down_conv = nn.Conv2d(input_nc, inner_nc, 4, 2, 1, bias=bias)
        if outermost:
            down = [down_conv]
            up = [nn.ReLU(), nn.ConvTranspose2d(inner_nc * 2, outer_nc, 4, 2, 1, bias=True)]
        elif innermost:
            down = [nn.LeakyReLU(0.2), down_conv]
            up = [nn.ReLU(), nn.ConvTranspose2d(inner_nc, outer_nc, 4, 2, 1, bias=bias), make_norm(norm, outer_nc)]
        else:
            down = [nn.LeakyReLU(0.2), down_conv, make_norm(norm, inner_nc)]
            up = [nn.ReLU(), nn.ConvTranspose2d(inner_nc * 2, outer_nc, 4, 2, 1, bias=bias), make_norm(norm, outer_nc)]
            if dropout > 0:
                up.append(nn.Dropout(dropout))
        middle = [] if submodule is None else [submodule]
        self.model = nn.Sequential(*down, *middle, *up)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.outermost:
            return self.model(x)
        return torch.cat([x, self.model(x)], dim=1)


class RefineHead(nn.Module):
    """(features, input) at full resolution -> output: ``layers`` 3x3 convolutions with ReLU over
    their concatenation, then a 1x1 convolution to the output channels (registered last, so
    ``start_from_fill`` zeroes it). He-initialised: there is no norm layer to rescale it."""

    def __init__(self, features: int, in_channels: int, out_channels: int, layers: int):
        super().__init__()
        blocks: list[nn.Module] = []
        channels = features + in_channels
        for _ in range(layers):
            conv = nn.Conv2d(channels, features, 3, 1, 1)
            nn.init.kaiming_normal_(conv.weight, nonlinearity="relu")
            nn.init.zeros_(conv.bias)
            blocks += [conv, nn.ReLU()]
            channels = features
        self.body = nn.Sequential(*blocks)
        self.out = nn.Conv2d(channels, out_channels, 1)

    def forward(self, features: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        return self.out(self.body(torch.cat([features, x], dim=1)))


class UNet(nn.Module):
    """(B, in_channels, H, W) -> (B, out_channels, H, W) for any H, W; `depth` >= 2 levels;
    ``refine`` full-resolution 3x3 layers after it (0: pix2pix's U-Net as it is)."""

    def __init__(
        self,
        in_channels: int = 1,
        out_channels: int = 1,
        ngf: int = 64,
        depth: int = 7,
        norm: str = "batch",
        dropout: float = 0.5,
        refine: int = 0,
    ):
        super().__init__()
        if depth < 2:
            raise ValueError(f"UNet depth must be >= 2, got {depth}")
        if not (isinstance(refine, int) and refine >= 0):
            raise ValueError(f"UNet refine must be an integer >= 0, got {refine!r}")
        self.depth = depth
        filters = [ngf * min(2**i, 8) for i in range(depth)]
        level = UNetLevel(filters[-2], filters[-1], innermost=True, norm=norm)
        for i in range(depth - 2, 0, -1):  # level i: outer filters[i-1], inner filters[i]
            p = dropout if i >= 4 else 0.0
            level = UNetLevel(filters[i - 1], filters[i], submodule=level, norm=norm, dropout=p)
        self.model = UNetLevel(ngf if refine else out_channels, filters[0], in_channels, level, outermost=True, norm=norm)
        init_weights(self)
        self.head = RefineHead(ngf, in_channels, out_channels, refine) if refine else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        m = 2**self.depth
        h, w = x.shape[-2:]
        padded = (-(-h // m) * m, -(-w // m) * m)
        y = self.model(match_size(x, padded, mode="replicate"))
        y = match_size(y, (h, w))
        return y if self.head is None else self.head(y, x)
