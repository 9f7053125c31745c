"""Exports of simulated and reconstructed terrain: USD stages, figures and datasets on disk."""

from .dataset import DatasetError, DiskPairs, shard_seed, write_dataset
from .figures import (
    load_predictor,
    load_terrain_setting,
    preview_figure,
    save_figure,
    terrain_setting_names,
    write_figures,
    write_preview,
    write_usd_figure,
)
from .usd import export_usd

__all__ = [
    "DatasetError",
    "DiskPairs",
    "export_usd",
    "load_predictor",
    "load_terrain_setting",
    "preview_figure",
    "save_figure",
    "shard_seed",
    "terrain_setting_names",
    "write_dataset",
    "write_figures",
    "write_preview",
    "write_usd_figure",
]
