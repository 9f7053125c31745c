"""Exports of simulated and reconstructed terrain: figures (and, later, USD, ONNX, datasets)."""

from .figures import load_terrain_setting, preview_figure, save_figure, terrain_setting_names, write_preview

__all__ = ["load_terrain_setting", "preview_figure", "save_figure", "terrain_setting_names", "write_preview"]
