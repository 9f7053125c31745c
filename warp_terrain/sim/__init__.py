"""The simulator: terrains, LIDAR scans and elevation maps, launched as Warp kernels."""

from .batch import Batch, DataConfig, SimConfig, as_sim_config, generate_batch
from .device import resolve_device
from .lidar import LidarConfig, lidar_preset, lidar_preset_names
from .projection import project_points
from .scan import cast_scans
from .switches import KernelSwitches, kernel_switches, use_kernel_switches
from .terrain import ObstacleConfig, TerrainConfig, fractal_heightfield

__all__ = [
    "Batch",
    "DataConfig",
    "KernelSwitches",
    "LidarConfig",
    "ObstacleConfig",
    "SimConfig",
    "TerrainConfig",
    "as_sim_config",
    "cast_scans",
    "fractal_heightfield",
    "generate_batch",
    "kernel_switches",
    "lidar_preset",
    "lidar_preset_names",
    "project_points",
    "resolve_device",
    "use_kernel_switches",
]
