"""A classical fill inside the network: push-pull interpolation, and a generator that corrects it.

``push_pull_fill`` fills the unobserved cells of a height map from the observed ones with a
normalised-convolution pyramid (the "push-pull" of Gortler et al., 1996): observed heights and
their weights are averaged down to 1x1, then each level's holes are filled from the level above,
bilinearly upsampled. Observed cells keep their heights exactly. It is a few pooling and
interpolation ops: differentiable, batched on the device, and exportable to ONNX.

``FillResidualGenerator`` wraps any generator so it predicts a correction to that fill: its
input is the fill and the mask (heights relative to the mean observed height, so the net does
not have to learn where the sensor is mounted), and its output is ``fill + correction``. Before
training it already is the classical fill; training only has to learn what the fill gets wrong.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def push_pull_fill(height: torch.Tensor, mask: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """(B, 1, H, W) heights and 0/1 mask -> the same heights with unobserved cells filled.

    A map with no observed cell comes back as zeros.
    """
    values = [height * mask]
    weights = [mask]
    while values[-1].shape[-1] > 1 or values[-1].shape[-2] > 1:
        values.append(F.avg_pool2d(values[-1], 2, ceil_mode=True))
        weights.append(F.avg_pool2d(weights[-1], 2, ceil_mode=True))
    estimate = values[-1] / weights[-1].clamp_min(eps)
    for v, w in zip(reversed(values[:-1]), reversed(weights[:-1])):
        coarse = F.interpolate(estimate, size=v.shape[-2:], mode="bilinear", align_corners=False)
        trust = (w * 4.0).clamp(max=1.0)  # a quarter-observed block is trusted fully
        estimate = trust * (v / w.clamp_min(eps)) + (1.0 - trust) * coarse
    return estimate


def mean_observed(height: torch.Tensor, mask: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """(B, 1, 1, 1) mean height of each map's observed cells (0 where none)."""
    return (height * mask).sum(dim=(2, 3), keepdim=True) / mask.sum(dim=(2, 3), keepdim=True).clamp_min(eps)


class FillResidualGenerator(nn.Module):
    """condition (B, 2, H, W) = (scan, mask) -> push-pull fill + net(fill - mean, mask)."""

    def __init__(self, net: nn.Module):
        super().__init__()
        self.net = net

    def forward(self, condition: torch.Tensor) -> torch.Tensor:
        scan, mask = condition[:, :1], condition[:, 1:2]
        fill = push_pull_fill(scan, mask)
        reference = mean_observed(scan, mask)
        return fill + self.net(torch.cat([fill - reference, mask], dim=1))


def unobserved_weight_map(mask: torch.Tensor, unobserved_weight: float) -> torch.Tensor:
    """Per-cell loss weights: 1 on observed cells, ``unobserved_weight`` elsewhere, mean 1."""
    weight = mask + unobserved_weight * (1.0 - mask)
    return weight / weight.mean(dim=(1, 2, 3), keepdim=True)
