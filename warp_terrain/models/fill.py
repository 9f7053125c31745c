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
With ``height_scale_min > 0`` the heights it sees are also divided by the map's spread of
observed heights (:func:`observed_spread`) and its correction multiplied by it: the net then
works in units of the map's own relief, so a 5 cm meadow and a 4 m hillside look alike to it.
A second output channel (``model.uncertainty``: a log-variance) is passed on, shifted by
``2 log s`` so that it too is in metres squared.
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


def observed_spread(height: torch.Tensor, mask: torch.Tensor, reference: torch.Tensor, floor: float) -> torch.Tensor:
    """(B, 1, 1, 1) standard deviation of each map's observed heights about ``reference``,
    at least ``floor`` (also for maps with no observed cell)."""
    var = (((height - reference) ** 2) * mask).sum(dim=(2, 3), keepdim=True) / mask.sum(dim=(2, 3), keepdim=True).clamp_min(1.0)
    return var.sqrt().clamp_min(floor)


class FillResidualGenerator(nn.Module):
    """condition (B, 2, H, W) = (scan, mask) -> push-pull fill + s * net((fill - mean) / s, mask),
    where s is 1, or the map's observed-height spread (>= ``height_scale_min`` metres) if > 0.
    Output channels after the first (a log-variance) come back as ``net + 2 log s``."""

    def __init__(self, net: nn.Module, height_scale_min: float = 0.0):
        super().__init__()
        self.net = net
        self.height_scale_min = float(height_scale_min)

    def forward(self, condition: torch.Tensor) -> torch.Tensor:
        scan, mask = condition[:, :1], condition[:, 1:2]
        fill = push_pull_fill(scan, mask)
        reference = mean_observed(scan, mask)
        if self.height_scale_min > 0:
            scale = observed_spread(scan, mask, reference, self.height_scale_min)
        else:  # metres: dividing and multiplying by exactly 1 changes no bit
            scale = torch.ones_like(reference)
        out = self.net(torch.cat([(fill - reference) / scale, mask], dim=1))
        height = fill + scale * out[:, :1]
        return height if out.shape[1] == 1 else torch.cat([height, out[:, 1:] + 2.0 * torch.log(scale)], dim=1)


def unobserved_weight_map(mask: torch.Tensor, unobserved_weight: float) -> torch.Tensor:
    """Per-cell loss weights: 1 on observed cells, ``unobserved_weight`` elsewhere, mean 1."""
    weight = mask + unobserved_weight * (1.0 - mask)
    return weight / weight.mean(dim=(1, 2, 3), keepdim=True)


def loss_weight_map(scan: torch.Tensor, mask: torch.Tensor, unobserved_weight: float = 1.0, relief_floor: float = 0.0) -> torch.Tensor | None:
    """Per-cell weights of the L1 (and NLL) terms, or None for the plain mean: unobserved cells
    weighted by ``unobserved_weight`` (:func:`unobserved_weight_map`), and with
    ``relief_floor > 0`` each map by ``1 / observed_spread`` (at least ``relief_floor``),
    normalised so the batch's mean weight is 1."""
    weight = unobserved_weight_map(mask, unobserved_weight) if unobserved_weight != 1.0 else None
    if relief_floor <= 0:
        return weight
    inverse = 1.0 / observed_spread(scan, mask, mean_observed(scan, mask), relief_floor)
    inverse = inverse / inverse.mean()
    return inverse.expand_as(mask) if weight is None else weight * inverse
