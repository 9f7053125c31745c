"""A reconstructed elevation map as a picture (``warp-terrain reconstruct --png``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .common import grid_extent, new_figure, save_figure


def save_map_preview(height, mask, map_cell: float, out, title: str = "", dpi: int = 80) -> Path:
    """A PNG of a reconstructed map beside its observation mask (axes in metres)."""
    height, mask = np.asarray(height), np.asarray(mask)
    extent = grid_extent(height.shape[0], map_cell)
    fig = new_figure((10, 4.4))
    axes = fig.subplots(1, 2)
    im = axes[0].imshow(height.T, origin="lower", extent=extent, cmap="viridis")
    axes[0].set_title("reconstructed elevation (sensor frame)")
    fig.colorbar(im, ax=axes[0], label="z (m)")
    axes[1].imshow(mask.T, origin="lower", extent=extent, cmap="gray", vmin=0, vmax=1)
    axes[1].set_title(f"observed cells ({100 * mask.mean():.1f} %)")
    for ax in axes:
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    if title:
        fig.suptitle(title)
    return save_figure(fig, out, dpi=dpi)
