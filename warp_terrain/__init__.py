"""warp-terrain: learn to fill in off-road elevation maps from simulated LIDAR.

Warp kernels generate terrains and ray-cast LIDAR scans on the device; the results reach
PyTorch zero-copy. The public API (names fixed by the design contract):

- ``fractal_heightfield``: batched fBm Perlin heightfields
- ``LidarConfig``, ``lidar_preset``: sensor patterns with published vertical-angle tables
- ``cast_scans``: LIDAR scans of heightfields, in each sensor frame
- ``project_points``: point clouds to elevation maps and observation masks
- ``generate_batch``: training pairs (scan, mask, target) from a config
- ``Reconstructor``: ``Reconstructor.load().reconstruct(points)``, a point cloud to a full map
- ``export_usd``: a terrain, its LIDAR points and a reconstruction as a USD stage
"""

import os as _os

import warp as _wp

# Warp prints its banner and every module compile; keep a library quiet unless asked.
if not _os.environ.get("WARP_TERRAIN_VERBOSE"):
    _wp.config.log_level = _wp.LOG_WARNING

from .core.version import __version__  # noqa: E402
from .export.usd import export_usd  # noqa: E402
from .inference.reconstructor import Reconstructor  # noqa: E402
from .sim import (  # noqa: E402
    Batch,
    DataConfig,
    LidarConfig,
    ObstacleConfig,
    SimConfig,
    TerrainConfig,
    cast_scans,
    fractal_heightfield,
    generate_batch,
    lidar_preset,
    project_points,
    use_kernel_switches,
)

__all__ = [
    "Batch",
    "DataConfig",
    "LidarConfig",
    "ObstacleConfig",
    "SimConfig",
    "TerrainConfig",
    "__version__",
    "cast_scans",
    "Reconstructor",
    "export_usd",
    "fractal_heightfield",
    "generate_batch",
    "lidar_preset",
    "project_points",
    "use_kernel_switches",
]
