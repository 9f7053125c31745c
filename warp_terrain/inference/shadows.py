"""The scan's shadows: the unobserved cells the sensor could not have seen over what it did see.

A map is centred on the sensor and its heights are z in the sensor frame (the LIDAR at height 0,
``DESIGN.md``). A ray from the sensor to a cell at horizontal distance ``r`` passes over every
cell in front of it; an observed cell ``k`` at ``r_k`` with height ``z_k`` bounds the line of
sight from below, so no surface at ``r`` lower than

    horizon(r) = r * max_k (z_k - margin) / r_k

can have been seen (``margin``: how far a measured height may lie above the ground's, e.g. a
few times the scan's own noise, ``models.noise.scan_noise``). An unobserved cell whose fill lies
below its horizon is in the shadow of something the scan shows: an obstacle's back, the far side
of a ridge. There the sensor gives no evidence at all, which the self-check's hidden cells (all of
them seen) cannot stand in for (``selfcheck.checked_maps``, ``keep_shadows``).

The rays are a table per map size (:func:`ray_cells`): for each cell the cells of the digital
line from the centre to it, one per row or column crossed, so one gather and a max answer a whole
batch. What the model cannot know: returns under an overhang (a canopy, a pole's top) were seen
past a 2.5-D occluder; the self-check refutes the horizon on such scans (its hidden cells, seen,
fall in shadow).
"""

from __future__ import annotations

import functools
import math

import torch


@functools.lru_cache(maxsize=8)
def ray_cells(size: int, device: str = "cpu") -> tuple[torch.Tensor, torch.Tensor]:
    """``(index, distance)`` of a ``size`` x ``size`` map centred on the sensor: for each cell
    (row-major) the cells of the digital line from the centre to it, the cell itself excluded,
    (S*S, L) int64 padded with ``S*S`` (a slot the caller fills with -inf); and each cell's
    distance from the centre in cells, (S, S) float32.

    A cell ``m`` rows or columns (whichever is more) from the centre gets the ``m - 1`` points at
    ``k / m`` of the way (k = 1 .. m-1) rounded to their cells: one cell per row or column crossed."""
    if isinstance(size, bool) or not isinstance(size, int) or size < 1:
        raise ValueError(f"ray_cells: size must be an integer >= 1, got {size!r}")
    centre = 0.5 * (size - 1)
    rows, cols = torch.meshgrid(torch.arange(size, dtype=torch.float64), torch.arange(size, dtype=torch.float64), indexing="ij")
    dy, dx = (rows - centre).flatten(), (cols - centre).flatten()
    steps = torch.maximum(dy.abs(), dx.abs()).ceil().clamp_min(1.0)  # (S*S,)
    length = max(int(steps.max().item()) - 1, 1)
    k = torch.arange(1, length + 1, dtype=torch.float64)  # (L,)
    t = k[None, :] / steps[:, None]
    r = torch.round(centre + dy[:, None] * t).long().clamp(0, size - 1)
    c = torch.round(centre + dx[:, None] * t).long().clamp(0, size - 1)
    index = r * size + c
    own = torch.arange(size * size)[:, None]
    pad = (k[None, :] >= steps[:, None]) | (index == own)  # past the cell, or the cell itself
    index = torch.where(pad, torch.full_like(index, size * size), index)
    distance = torch.sqrt(dx * dx + dy * dy).view(size, size).float()
    return index.to(device), distance.to(device)


def horizon(scan: torch.Tensor, mask: torch.Tensor, margin: torch.Tensor | float = 0.0) -> torch.Tensor:
    """(B, 1, S, S) metres: the lowest height the sensor (the map's centre, height 0) could have
    seen at each cell over the observed cells in front of it, each lowered by ``margin`` (metres;
    a float or (B, 1, 1, 1)); -inf where no observed cell lies in front (the centre cell's
    distance 0 bounds nothing)."""
    if scan.dim() != 4 or scan.shape[1] != 1 or scan.shape[-1] != scan.shape[-2] or mask.shape != scan.shape:
        raise ValueError(f"horizon: need scan and mask of one shape (B, 1, S, S), got {tuple(scan.shape)} and {tuple(mask.shape)}")
    b, size = scan.shape[0], scan.shape[-1]
    index, distance = ray_cells(size, str(scan.device))
    distance = distance.to(scan.dtype)
    seen = (mask > 0) & (distance > 0)
    slope = torch.where(seen, (scan - margin) / distance.clamp_min(1.0), torch.full_like(scan, -math.inf))
    slope = torch.cat([slope.flatten(1), slope.new_full((b, 1), -math.inf)], dim=1)
    best = slope[:, index].amax(dim=2).view(b, 1, size, size)
    return torch.where(torch.isfinite(best), best * distance, best)


def shadow_cells(scan: torch.Tensor, mask: torch.Tensor, fill: torch.Tensor, margin: torch.Tensor | float = 0.0) -> torch.Tensor:
    """(B, 1, S, S) bool: the unobserved cells whose ``fill`` lies below their :func:`horizon`."""
    return (mask <= 0) & (fill < horizon(scan, mask, margin))
