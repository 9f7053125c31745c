"""A model that checks itself on the scan in front of it, and falls back to its classical fill.

A network trained on simulated worlds can meet ground unlike any it saw; nothing tells it so.
The scan itself can: hide a share of its observed cells, fill the map again with the model and
with the model's base fill (the classical fill it corrects), and compare both with the heights
the sensor measured in the hidden cells. The blend ``fill + w (model - fill)`` whose error on
those cells is least has

    w* = sum(d (z - f)) / sum(d^2),   d = model - f on the hidden cells, z the measured heights,

the least-squares weight of the correction, clamped to [0, 1]. The map's full-scan prediction
then keeps ``w*`` of its correction: all of it where the model beats its fill on this scan, none
where it does worse (the map is then the classical fill), in between where it helps a little.
The fill itself is chosen the same way, per map, between the model's base fill and the plain
thin plate (``candidate_fills``): whichever errs less on the hidden cells. A label-free check of
every map, at the cost of a second pass on the thinned scan.
"""

from __future__ import annotations

import torch

from ..models.biharmonic import biharmonic_fill

#: Share of a map's observed cells hidden for the check (the real-data suite hides 20 % too).
CHECK_SHARE = 0.2
#: Seed of the cells hidden: the same scan gets the same check, so predictions repeat.
CHECK_SEED = 0x5E1F


def hidden_cells(mask: torch.Tensor, share: float = CHECK_SHARE, seed: int = CHECK_SEED) -> torch.Tensor:
    """(B, 1, S, S) bool: about ``share`` of each map's observed cells, drawn from ``seed``."""
    generator = torch.Generator(device="cpu").manual_seed(seed)
    draw = torch.rand(mask.shape, generator=generator).to(mask.device)
    return (mask > 0) & (draw < share)


def correction_weight(model: torch.Tensor, fill: torch.Tensor, measured: torch.Tensor, hidden: torch.Tensor) -> torch.Tensor:
    """(B, 1, 1, 1) least-squares weight of ``model - fill`` against ``measured - fill`` on the
    ``hidden`` cells, clamped to [0, 1] (0 where the correction is zero on them)."""
    h = hidden.to(model.dtype)
    d = (model - fill) * h
    num = (d * (measured - fill)).sum(dim=(2, 3), keepdim=True)
    den = (d * d).sum(dim=(2, 3), keepdim=True)
    return torch.where(den > 0, num / den.clamp_min(1e-30), torch.zeros_like(den)).clamp(0.0, 1.0)


def candidate_fills(base: torch.Tensor, scan: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(K, B, 1, S, S): the model's base fill ``base`` of the scan and the plain thin plate of it."""
    return torch.stack([base, biharmonic_fill(scan, mask)])


def chosen_fill(base: torch.Tensor, scan: torch.Tensor, mask: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """(B, 1, S, S): ``pick(candidate_fills(base, scan, mask), index)``, the thin plate solved only
    for the maps that chose it (candidate 1): one solve less per map that keeps its base fill."""
    thin = index == 1
    if not bool(thin.any()):
        return base
    out = base.clone()
    out[thin] = biharmonic_fill(scan[thin], mask[thin])
    return out


def best_fill(candidates: torch.Tensor, measured: torch.Tensor, hidden: torch.Tensor) -> torch.Tensor:
    """(B,) index of the candidate with the least squared error on each map's hidden cells."""
    h = hidden.to(candidates.dtype)
    errors = (((candidates - measured) * h) ** 2).sum(dim=(2, 3, 4))  # (K, B)
    return errors.argmin(dim=0)


def pick(candidates: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """(B, 1, S, S): candidate ``index[b]`` of each map ``b``."""
    return candidates[index, torch.arange(candidates.shape[1], device=candidates.device)]
