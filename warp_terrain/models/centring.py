"""Each observed cell's height moved to the cell's centre: what a map's cell should hold.

A cell's height is the mean of its returns, and its returns lie where the LIDAR's rings cross
the cell, not at its centre: on ground of gradient ``g`` their mean is the height at their mean
position, off the centre's by ``g . d`` (``d``: the mean offset, ``sim.projection.cell_offsets``).
Along a ring every cell is crossed alike, so the error is shared by neighbouring cells, and no
filter of the map alone can tell it from the ground (the shipped self-check's ``scan_noise``
sees a third of it). ``centre_cells`` subtracts ``g . d`` with ``g`` the gradient of the thin
plate (``biharmonic_fill``) of the map, the smoothest surface through the observed cells,
defined between rings and in the holes too, averaged over ``span`` metres (a box of cells; a
plane's gradient is constant, so a plane stays exact), refitted ``solves`` times on the moved
heights. Unaveraged, the gradient of a noisy scan is its noise's: on the evaluation's scans
with 10 % image noise the moved heights then erred 8 % more than the mean heights, and the
shipped model's maps 5 % more (``tools/probes/cell_centre.py --noisy --span 0``). The
gradient's length is clamped at ``max_slope``: at a wall the thin plate's gradient is the
step's, and a cell at a wall's foot holds returns of the wall, not of a slope. Pure torch, batched; the cost is the thin plate's solve (16 ms for one 121-cell map on this
CPU's one thread).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from .biharmonic import DEFAULT_STEPS, biharmonic_fill

#: The steepest gradient the correction applies (1: 45 degrees); steeper is a step, not a slope.
MAX_SLOPE = 1.0
#: Metres over which the thin plate's gradient is averaged (9 cells of 0.25 m): the thin plate
#: passes through every observed height, noise included, and its gradient between two noisy
#: cells is the noise's; averaged over a few metres it is the ground's.
GRADIENT_SPAN = 2.0


def centre_cells(scan: torch.Tensor, mask: torch.Tensor, offset: torch.Tensor, map_cell: float, max_slope: float = MAX_SLOPE,
                 solves: int = 1, span: float = GRADIENT_SPAN, steps: tuple[int, ...] = DEFAULT_STEPS) -> torch.Tensor:
    """(B, 1, S, S): ``scan`` with each observed cell's height moved from its returns' mean
    position to the cell's centre, ``h - g . offset``; unobserved cells 0.

    ``scan``, ``mask``: (B, 1, S, S) mean heights and observation mask (``project_points``);
    ``offset``: (B, 2, S, S) the returns' mean offsets in metres (``cell_offsets``);
    ``map_cell``: the cells' size in metres (the gradient's unit); ``span``: metres over which
    the gradient is averaged (a box of ``2 round(span / (2 map_cell)) + 1`` cells a side, 9 by
    default; 0: none); ``steps``: the thin plate's CG steps per level (``biharmonic_fill``; its
    defaults stop short of the exact solve by a fraction of a per cent, more steps come nearer)."""
    if scan.dim() != 4 or scan.shape[1] != 1 or mask.shape != scan.shape:
        raise ValueError(f"scan {tuple(scan.shape)}, mask {tuple(mask.shape)}: must both be (B, 1, S, S)")
    if offset.shape != (scan.shape[0], 2, *scan.shape[2:]):
        raise ValueError(f"offset {tuple(offset.shape)}: must be (B, 2, S, S) = {(scan.shape[0], 2, *scan.shape[2:])}")
    if not map_cell > 0 or not max_slope >= 0 or solves < 1 or not span >= 0:
        raise ValueError(f"map_cell={map_cell}, max_slope={max_slope}, solves={solves}, span={span}: "
                         "need map_cell > 0, max_slope >= 0, solves >= 1, span >= 0")
    width = 2 * round(span / (2.0 * map_cell)) + 1
    observed = mask > 0
    scan = torch.where(observed, scan, torch.zeros_like(scan))
    if min(scan.shape[2:]) < 2:  # no gradient on a map one cell wide
        return scan
    height = scan
    for _ in range(solves):
        surface = biharmonic_fill(height, mask, tension=0.0, steps=steps)
        gradient = torch.cat(torch.gradient(surface, spacing=float(map_cell), dim=(2, 3)), dim=1)  # central inside, one-sided at the edges
        if width > 1:  # the mean over the window's cells inside the map
            gradient = F.avg_pool2d(gradient, width, stride=1, padding=width // 2, count_include_pad=False)
        gx, gy = gradient[:, :1], gradient[:, 1:]
        length = torch.sqrt(gx * gx + gy * gy)
        shrink = torch.where(length > max_slope, max_slope / length.clamp_min(1e-12), torch.ones_like(length))
        moved = scan - shrink * (gx * offset[:, :1] + gy * offset[:, 1:])
        height = torch.where(observed, moved, torch.zeros_like(scan))
    return height
