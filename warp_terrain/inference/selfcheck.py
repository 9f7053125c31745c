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

What the check measures is how the model does next to measured cells: a hidden cell has kept
cells around it. Far from every measured cell (a long shadow, the map's corners beyond the
sensor's range) the model may do better or worse than there: measured per distance band, the
model trained on the mixed world loses to the thin plate next to measured cells of clean scans
and beats it far from them on real terrain. With ``check_reach`` the scan is asked a second
question: hide its outermost observed cells (``outer_cells``: the gap they leave is as wide as
the outer rings' spacing) and weigh the correction there the same way (``w_far``). The map then
keeps ``w = w* (1 - far) + w_far far`` of its correction, ``far = far_share(mask)`` rising from
0 at ``REACH_NEAR`` cells from the nearest observed cell to 1 at ``REACH_FAR``: the near check
next to the scan, the far check away from it. Both groups are hidden in the same pass, so the
reach costs no extra pass of the model.
"""

from __future__ import annotations

import torch

from ..models.biharmonic import biharmonic_fill

#: Share of a map's observed cells hidden for the check (the real-data suite hides 20 % too).
CHECK_SHARE = 0.2
#: Seed of the cells hidden: the same scan gets the same check, so predictions repeat.
CHECK_SEED = 0x5E1F
#: Cells (chessboard distance to the nearest observed cell) up to which the checked weight holds:
#: the reach of the check, whose hidden cells lie next to kept ones.
REACH_NEAR = 2
#: Cells from which the weight measured on the outer cells (``outer_cells``) holds alone.
REACH_FAR = 8


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


def candidate_fills(bases: torch.Tensor, scans: torch.Tensor, masks: torch.Tensor) -> torch.Tensor:
    """(K, N, 1, S, S): for each of the ``N`` maps, the model's base fill (``bases``) and the
    plain thin plate of its scan, every thin plate in one batched solve (the self-check passes
    the scan and its thinned copy together: one call costs less than two on a CPU)."""
    return torch.stack([bases, biharmonic_fill(scans, masks)])


def best_fill(candidates: torch.Tensor, measured: torch.Tensor, hidden: torch.Tensor) -> torch.Tensor:
    """(B,) index of the candidate with the least squared error on each map's hidden cells."""
    h = hidden.to(candidates.dtype)
    errors = (((candidates - measured) * h) ** 2).sum(dim=(2, 3, 4))  # (K, B)
    return errors.argmin(dim=0)


def pick(candidates: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """(B, 1, S, S): candidate ``index[b]`` of each map ``b``."""
    return candidates[index, torch.arange(candidates.shape[1], device=candidates.device)]


def far_share(mask: torch.Tensor, near: int = REACH_NEAR, far: int = REACH_FAR) -> torch.Tensor:
    """(B, 1, S, S) in [0, 1]: 0 within ``near`` cells (chessboard distance) of an observed cell,
    1 from ``far`` cells on, linear in the distance between; 1 everywhere on a map with no
    observed cell. The distance comes from ``far`` 3x3 dilations of the observed cells."""
    if not (isinstance(near, int) and isinstance(far, int) and 0 <= near < far):
        raise ValueError(f"far_share: need integers 0 <= near < far, got near={near!r}, far={far!r}")
    reached = (mask > 0).to(torch.float32)
    distance = torch.zeros_like(reached)
    for _ in range(far):
        distance = distance + (1.0 - reached)  # cells not yet reached are one dilation farther
        reached = torch.nn.functional.max_pool2d(reached, 3, stride=1, padding=1)
    return ((distance - near) / (far - near)).clamp(0.0, 1.0).to(mask.dtype if mask.is_floating_point() else torch.float32)


#: Share of each map's observed cells, the farthest from the sensor, hidden for the far check.
OUTER_SHARE = 0.3


def outer_cells(mask: torch.Tensor, share: float = OUTER_SHARE) -> torch.Tensor:
    """(B, 1, S, S) bool: each map's observed cells farthest from its centre (the sensor), the
    outermost ``share`` of them by distance. Hidden, they leave a gap as wide as the spacing of
    the outer rings: what the model's correction does far from the kept cells can be measured
    there, as the random cells of ``hidden_cells`` measure it next to them."""
    size = mask.shape[-1]
    axis = torch.arange(size, device=mask.device, dtype=torch.float32) - 0.5 * (size - 1)
    radius = torch.sqrt(axis[:, None] ** 2 + axis[None, :] ** 2).expand(mask.shape)
    observed = mask > 0
    # per map: the radius below which 1 - share of its observed cells lie (NaN, and no cell, if none)
    cut = torch.nanquantile(torch.where(observed, radius, torch.nan).flatten(1), 1.0 - share, dim=1)
    return observed & (radius > cut.view(-1, 1, 1, 1))
