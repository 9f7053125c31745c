"""LIDAR scans of heightfields: the Python side of ``kernels/raycast.py``."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import torch
import warp as wp

from ..core.checks import check_finite, require
from ..kernels import clutter as clutter_kernels
from ..kernels import heightfield as heightfield_kernels
from ..kernels import raycast as raycast_kernels
from . import arena
from .arena import as_seed
from .clutter import CanopyLayer, no_canopy
from .device import resolve_device, to_warp, torch_stream
from .lidar import LidarConfig
from .switches import kernel_switches
from .threads import run_parts, split_threads

TILE = raycast_kernels.TILE_CELLS  # cells per side of the max-height tiles that let rays skip empty space
VERTICAL_DEG = 89.9  # rings steeper than this are cast one ray at a time (no horizontal walk)
THREAD_MIN_RAYS = 8192  # rays per CPU thread below which splitting a scan does not pay (~2 ms of walking)


@lru_cache(maxsize=32)
def _directions(key: tuple, device: str) -> wp.array:
    elevations, step, start, fov = key
    lidar = LidarConfig(elevations_deg=list(elevations), azimuth_step_deg=step, azimuth_start_deg=start, fov_deg=fov)
    return wp.array(lidar.ray_directions(), dtype=wp.vec3, device=device)


def ray_directions(lidar: LidarConfig, device: str) -> wp.array:
    """The sensor's unit ray directions as a Warp array, cached per sensor pattern and device."""
    key = (tuple(float(e) for e in lidar.elevations_deg), float(lidar.azimuth_step_deg), float(lidar.azimuth_start_deg), float(lidar.fov_deg))
    return _directions(key, device)


def columns_walkable(lidar: LidarConfig) -> bool:
    """Whether one walk per azimuth column can serve every ring (``kernels/raycast.py``
    ``cast_columns``): true unless a ring points straight up or down."""
    return bool(np.all(np.abs(np.asarray(lidar.elevations_deg, dtype=np.float64)) < VERTICAL_DEG))


def trace(
    heights: wp.array,
    cell: float,
    lidar: LidarConfig,
    seed,
    device: str,
    augment: bool = False,
    reach: float = 0.0,
    columns: range | None = None,
    out: wp.array | None = None,
    canopy: CanopyLayer | None = None,
    per_ray: bool = False,
    threads: int = 1,
) -> tuple[wp.array, wp.array]:
    """Cast every ray of ``lidar`` over every heightfield in one launch.

    ``reach > 0`` stops rays where they leave the square ``+-reach`` m around the sensor.
    ``columns`` (a ``range`` of azimuth columns) casts only those columns (every ring), writing their rays
    into ``out`` (a ``(batch, rays)`` vec3 array; other rays are left as they are): how
    ``sim/parallel.py`` splits one scan across processes.
    ``canopy`` (``sim/clutter.py``) adds the clutter layer above the ground; the rays are then
    walked one by one (``cast_rays``: the column walk's invariant does not hold under an
    overhanging or porous layer), so ``columns`` must be the whole scan. ``per_ray`` walks
    every ray on its own without clutter too.
    ``threads > 1`` (CPU) splits the column walk's columns over that many threads
    (``sim/threads.py``): the same points, bit for bit; the per-ray walk stays one launch.

    Returns ``(points, sensor_z)``: ``(batch, rays)`` vec3 hits in each sensor frame (NaN where
    no return) and each sensor's world height.
    """
    batch, H, W = heights.shape
    seed = as_seed(seed, device)
    directions = ray_directions(lidar, device)
    tiles = (batch, (H - 2) // TILE + 1, (W - 2) // TILE + 1)
    tile_max = arena.empty(tiles, float, device)
    terrain_max = arena.full(batch, -1.0e30, float, device)
    sensor_z = arena.empty(batch, float, device)
    points = out if out is not None else arena.empty((batch, directions.shape[0]), wp.vec3, device)
    rings = lidar.channels
    by_column = columns_walkable(lidar) and canopy is None and not per_ray
    total = directions.shape[0] // rings
    columns = columns if columns is not None else range(total)
    require(isinstance(columns, range) and len(columns) > 0 and columns.step > 0 and 0 <= columns.start and columns[-1] < total
            and (by_column or len(columns) == total), "columns", columns, f"must be a non-empty range within [0, {total}) of a scan with no vertical ring")
    wp.launch(heightfield_kernels.tile_max_heights, dim=tiles, inputs=[heights, TILE], outputs=[tile_max, terrain_max], device=device)
    if canopy is not None:
        require(tuple(canopy.top.shape) == (batch, H - 1, W - 1), "canopy", f"shape {tuple(canopy.top.shape)}", f"must be one value per cell: {(batch, H - 1, W - 1)}")
        wp.launch(clutter_kernels.raise_tiles, dim=canopy.top.shape, inputs=[canopy.top, canopy.density, TILE], outputs=[tile_max, terrain_max], device=device)
    wp.launch(heightfield_kernels.sensor_heights, dim=batch, inputs=[heights, float(lidar.mount_height)], outputs=[sensor_z], device=device)
    returns = [float(lidar.min_range), float(lidar.max_range), float(lidar.range_noise_std), float(lidar.dropout)]  # what a return goes through
    sample = [seed.array, int(bool(augment))]
    common = [*returns, float(reach), *sample]
    if by_column:
        switches = kernel_switches()
        kernel = raycast_kernels.column_kernel(switches.static_tile, switches.deferred_writes)
        # deferred: the walk stores distances, one pass over the same columns writes the returns
        ranges = arena.empty(points.shape if switches.deferred_writes else (0, 0), float, device)
        parts = [columns[k::threads] for k in range(min(threads, len(columns)))] if device == "cpu" else [columns]
        if len(parts) > 1:
            kernel.module.load(device)  # compile/load once, not from several threads

        def cast(part: range) -> None:
            wp.launch(
                kernel,
                dim=(batch, len(part)),
                inputs=[heights, tile_max, terrain_max, sensor_z, TILE, float(cell), directions, rings, part.start, part.step, *common],
                outputs=[points, ranges],
                device=device,
            )

        run_parts(cast, parts)
        if switches.deferred_writes:
            wp.launch(raycast_kernels.write_returns, dim=(batch, rings, len(columns)),
                      inputs=[ranges, directions, rings, columns.start, columns.step, *returns, *sample], outputs=[points], device=device)
    else:
        wp.launch(
            raycast_kernels.cast_rays,
            dim=points.shape,
            inputs=[heights, tile_max, terrain_max, sensor_z, TILE, float(cell), directions, *common,
                    canopy.struct() if canopy is not None else no_canopy(device)],
            outputs=[points],
            device=device,
        )
    return points, sensor_z


def as_heightfields(heights, name: str = "heights") -> tuple[object, tuple[int, int, int]]:
    """Check a ``(H, W)`` or ``(batch, H, W)`` heightfield and give it a batch axis."""
    shape = tuple(heights.shape) if hasattr(heights, "shape") else np.shape(heights)
    require(len(shape) in (2, 3), name, f"shape {shape}", "must be (H, W) or (batch, H, W)")
    if len(shape) == 2:
        heights = heights.reshape((1, *shape)) if isinstance(heights, wp.array) else heights[None]
        shape = (1, *shape)
    require(shape[0] >= 1 and shape[1] >= 2 and shape[2] >= 2, name, f"shape {shape}", "needs batch >= 1 and H, W >= 2")
    if isinstance(heights, wp.array):
        return heights, shape
    if isinstance(heights, torch.Tensor) and heights.device.type != "cpu":
        finite = torch.isfinite(heights).all().item()
    else:  # numpy on one thread: torch's OpenMP pool can stall a small check on a busy machine
        finite = np.isfinite(heights.detach().to(torch.float32).numpy() if isinstance(heights, torch.Tensor) else np.asarray(heights)).all()
    require(bool(finite), name, "array", "must hold only finite heights")
    return heights, shape


def cast_scans(heights, cell: float, lidar: LidarConfig, seed: int = 0, device=None, threads: int | None = None) -> torch.Tensor:
    """Simulated LIDAR scans of heightfields.

    ``heights``: ``(batch, H, W)`` or ``(H, W)`` metres (torch tensor or numpy array), vertex
    (i, j) at ``x = (i - (H-1)/2) * cell``, ``y = (j - (W-1)/2) * cell``. Each sensor sits
    ``lidar.mount_height`` above the surface at the heightfield's centre.
    Returns ``(batch, rays, 3)`` float32 points in each sensor frame, NaN rows for rays with no
    return; ray ``ring * columns + column`` follows ``lidar.ray_directions()``.
    ``threads``: CPU threads to walk the scans' columns with (``None``: every usable core, where
    each gets at least ``THREAD_MIN_RAYS`` rays); the points do not depend on it.
    """
    check_finite("cell", cell)
    require(cell > 0, "cell", cell, "must be > 0")
    require(isinstance(lidar, LidarConfig), "lidar", type(lidar).__name__, "must be a LidarConfig (see lidar_preset)")
    lidar.validate()
    heights, shape = as_heightfields(heights)
    device = resolve_device(device)
    threads = split_threads(threads, shape[0] * lidar.num_rays, THREAD_MIN_RAYS, device)
    with torch_stream(device):
        points, _ = trace(to_warp(heights, wp.float32, device), float(cell), lidar, int(seed), device, threads=threads)
    return wp.to_torch(points).view(points.shape[0], points.shape[1], 3)
