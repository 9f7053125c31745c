"""Ground projection of point clouds into elevation maps: the Python side of ``kernels/projection.py``."""

from __future__ import annotations

import numpy as np
import torch
import warp as wp

from ..core.checks import check_finite, require
from ..core.geometry import MAP_CELL, MAP_SIZE
from ..kernels import projection as projection_kernels
from . import arena
from .device import resolve_device, to_warp, torch_stream


def bin_into_maps(points: wp.array, map_size: int, map_cell: float, device: str, fill: float = 0.0):
    """``(height, top, mask)`` Warp arrays ``(batch, 1, S, S)`` from ``(batch, rays)`` vec3 points."""
    batch = points.shape[0]
    grid = (batch, map_size, map_size)
    height_sum = arena.zeros(grid, wp.float64, device)
    count = arena.zeros(grid, int, device)
    height_max = arena.full(grid, -1.0e30, float, device)
    wp.launch(projection_kernels.bin_points, dim=points.shape, inputs=[points, float(map_cell)], outputs=[height_sum, count, height_max], device=device)
    maps = [arena.empty((batch, 1, map_size, map_size), float, device) for _ in range(3)]
    wp.launch(projection_kernels.finish_maps, dim=grid, inputs=[height_sum, count, height_max, float(fill)], outputs=maps, device=device)
    return tuple(maps)


def check_map(map_size, map_cell) -> None:
    require(isinstance(map_size, (int, np.integer)) and not isinstance(map_size, bool), "map_size", map_size, "must be an integer")
    require(map_size >= 1, "map_size", map_size, "must be >= 1")
    check_finite("map_cell", map_cell)
    require(map_cell > 0, "map_cell", map_cell, "must be > 0")


def _real_points(points):
    """``points`` as a torch tensor or numpy array of real numbers (ints or floats); anything
    else (bool, complex, strings, objects, ragged lists) -> ValueError naming ``points``."""
    if isinstance(points, torch.Tensor):
        ok, dtype = not (points.is_complex() or points.dtype == torch.bool), points.dtype
    else:
        try:
            points = np.asarray(points)
        except (TypeError, ValueError) as err:
            raise ValueError(f"points: not an array of numbers ({err})") from None
        dtype = points.dtype
        ok = dtype.kind in "iuf"  # ints and floats; not bool, complex, timedelta, objects
    require(ok, "points", f"dtype {dtype}", "must be real numbers (float or int)")
    return points


def _checked_points(points, map_size: int, map_cell: float, device):
    """``(points (batch, rays, 3), or None for no rays; batch; device)`` after the checks
    ``project_points`` documents."""
    check_map(map_size, map_cell)
    points = _real_points(points)
    shape = tuple(points.shape)
    require(len(shape) in (2, 3) and shape[-1] == 3, "points", f"shape {shape}", "must be (rays, 3) or (batch, rays, 3)")
    if len(shape) == 2:
        points = points[None]
        shape = (1, *shape)
    require(shape[0] >= 1, "points", f"shape {shape}", "needs a batch of at least one scan")
    if device is None and isinstance(points, torch.Tensor):
        device = points.device.type if points.device.type == "cpu" else str(points.device)
    device = resolve_device(device)
    if shape[1] == 0:
        return None, shape[0], device
    if isinstance(points, torch.Tensor) and not points.is_floating_point():
        points = points.float()
    return points, shape[0], device


def _to_warp(points, device: str) -> wp.array:
    with np.errstate(over="ignore"):  # float64 beyond float32's range -> inf: skipped like NaN
        return to_warp(points, wp.vec3, device)


def project_points(points, map_size: int = MAP_SIZE, map_cell: float = MAP_CELL, device=None) -> tuple[torch.Tensor, torch.Tensor]:
    """Bin sensor-frame points into ``(height, mask)`` elevation maps, each ``(batch, 1, S, S)``.

    ``points``: ``(rays, 3)`` or ``(batch, rays, 3)``, torch or numpy. Point (x, y, z) lands in
    cell ``(round(x / map_cell + (S-1)/2), round(y / map_cell + (S-1)/2))``; a cell's height is
    the mean z of its points (0 where none landed) and its mask 1 where at least one did. Rows
    with NaN/inf and points outside the map are ignored (float64 values beyond float32's range
    count as inf); bool, complex or non-numeric points raise ValueError. ``device=None`` keeps a
    tensor's device.
    """
    points, batch, device = _checked_points(points, map_size, map_cell, device)
    if points is None:
        zeros = torch.zeros((batch, 1, map_size, map_size), device=device)
        return zeros, zeros.clone()
    with torch_stream(device):
        wp_points = _to_warp(points, device)
        height, _top, mask = bin_into_maps(wp_points, int(map_size), float(map_cell), device)
    return wp.to_torch(height), wp.to_torch(mask)


def cell_offsets(points, map_size: int = MAP_SIZE, map_cell: float = MAP_CELL, device=None) -> torch.Tensor:
    """``(batch, 2, S, S)`` metres: the mean horizontal offset (x, then y) of each cell's points
    from the cell's centre, 0 where none landed; the cells, checks and ignored rows of
    :func:`project_points`. A cell's mean height is the ground's height where its points lie,
    not at its centre: on a slope ``g`` it is off by ``g . offset`` (``models.centring``)."""
    points, batch, device = _checked_points(points, map_size, map_cell, device)
    if points is None:
        return torch.zeros((batch, 2, map_size, map_size), device=device)
    with torch_stream(device):
        wp_points = _to_warp(points, device)
        grid = (batch, int(map_size), int(map_size))
        offset_sum = arena.zeros((batch, 2, *grid[1:]), wp.float64, device)
        count = arena.zeros(grid, int, device)
        wp.launch(projection_kernels.bin_offsets, dim=wp_points.shape, inputs=[wp_points, float(map_cell)], outputs=[offset_sum, count], device=device)
        offset = arena.empty((batch, 2, *grid[1:]), float, device)
        wp.launch(projection_kernels.finish_offsets, dim=offset.shape, inputs=[offset_sum, count], outputs=[offset], device=device)
    return wp.to_torch(offset)
