"""Small pieces the networks share: the norm-layer factory, pix2pix weight init, size matching."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def make_norm(kind: str, channels: int) -> nn.Module:
    """`batch` | `instance` | `none`, configured as pix2pix does.

    Instance norm has no affine parameters and no running statistics (pix2pix's choice).
    """
    if kind == "batch":
        return nn.BatchNorm2d(channels, affine=True, track_running_stats=True)
    if kind == "instance":
        return nn.InstanceNorm2d(channels, affine=False, track_running_stats=False)
    if kind == "none":
        return nn.Identity()
    raise ValueError(f"unknown norm {kind!r}: expected batch, instance or none")


def conv_bias(norm: str) -> bool:
    """Whether a conv followed by `norm` needs its own bias (batch norm brings a shift; pix2pix)."""
    return norm != "batch"


def init_weights(net: nn.Module, gain: float = 0.02) -> nn.Module:
    """pix2pix's `normal` init: conv weights N(0, gain), batch-norm weights N(1, gain), biases 0."""
    for m in net.modules():
        if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d, nn.Linear)):
            nn.init.normal_(m.weight, 0.0, gain)
            if m.bias is not None:
                nn.init.zeros_(m.bias)
        elif isinstance(m, nn.BatchNorm2d):
            nn.init.normal_(m.weight, 1.0, gain)
            nn.init.zeros_(m.bias)
    return net


def split(total: int) -> tuple[int, int]:
    """Split a pad (positive) or crop (negative) amount into (before, after).

    The odd element goes at the end, as TensorFlow's "same" padding and Keras' defaults do.
    """
    before = total // 2 if total >= 0 else -((-total) // 2)
    return before, total - before


def match_size(x: torch.Tensor, size, mode: str = "constant") -> torch.Tensor:
    """Centre-crop and/or pad the last two dims of `x` to `size` = (H, W).

    Cropping is plain slicing; padding uses `mode` ("constant" = zeros, or "replicate").
    A no-op (the same tensor) when the size already matches.
    """
    h, w = int(size[0]), int(size[1])
    (t, b), (l, r) = split(h - x.shape[-2]), split(w - x.shape[-1])
    if min(t, b, l, r) < 0:  # crop first
        x = x[..., max(-t, 0) : x.shape[-2] - max(-b, 0), max(-l, 0) : x.shape[-1] - max(-r, 0)]
    if max(t, b, l, r) > 0:
        x = F.pad(x, (max(l, 0), max(r, 0), max(t, 0), max(b, 0)), mode=mode)
    return x
