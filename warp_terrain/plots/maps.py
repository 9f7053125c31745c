"""A reconstructed elevation map as a picture (the PNG ``warp-terrain reconstruct`` writes)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.colors import BoundaryNorm, ListedColormap

from .common import grid_extent, new_figure, save_figure

#: The panels of ``map_preview_figure``, left to right.
MAP_PANELS = ("height", "mask", "uncertainty")


def map_preview_figure(height, mask, map_cell: float, uncertainty=None, title: str = ""):
    """A figure of a reconstructed map: height, observation mask and uncertainty (sigma), side by
    side in the sensor frame (axes in metres, x right, y up), each with a labelled colour bar.
    Without ``uncertainty`` the third panel says the model predicts none (and has no colour bar)."""
    height, mask = np.asarray(height), np.asarray(mask)
    if height.ndim != 2 or height.shape != mask.shape or height.shape[0] != height.shape[1]:
        raise ValueError(f"height, mask: expected two (S, S) arrays, got shapes {height.shape} and {mask.shape}")
    if uncertainty is not None and np.shape(uncertainty) != height.shape:
        raise ValueError(f"uncertainty: shape {np.shape(uncertainty)} is not the map's {height.shape}")
    extent = grid_extent(height.shape[0], map_cell)
    fig = new_figure((15, 4.6))
    axes = fig.subplots(1, len(MAP_PANELS))
    im = axes[0].imshow(height.T, origin="lower", extent=extent, cmap="viridis")
    axes[0].set_title("reconstructed height (sensor frame)")
    fig.colorbar(im, ax=axes[0], label="z (m)")
    im = axes[1].imshow(mask.T, origin="lower", extent=extent, cmap=ListedColormap(["0.12", "0.95"]),
                        norm=BoundaryNorm([-0.5, 0.5, 1.5], 2))
    axes[1].set_title(f"observed cells ({100 * mask.mean():.1f} %)")
    fig.colorbar(im, ax=axes[1], label="mask (1 = observed, 0 = not)", ticks=[0, 1])
    if uncertainty is None:
        axes[2].set_facecolor("0.92")
        axes[2].text(0.5, 0.5, "no uncertainty:\nthe model predicts none", ha="center", va="center", transform=axes[2].transAxes)
        axes[2].set_xlim(extent[:2])
        axes[2].set_ylim(extent[2:])
        axes[2].set_title("uncertainty")
    else:
        im = axes[2].imshow(np.asarray(uncertainty).T, origin="lower", extent=extent, cmap="magma")
        axes[2].set_title("uncertainty (std. dev. of the height)")
        fig.colorbar(im, ax=axes[2], label="sigma (m)")
    for ax in axes:
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    if title:
        fig.suptitle(title)
    return fig


def save_map_preview(height, mask, map_cell: float, out, title: str = "", dpi: int = 80, uncertainty=None) -> Path:
    """A PNG of ``map_preview_figure`` at ``out``, written atomically."""
    return save_figure(map_preview_figure(height, mask, map_cell, uncertainty=uncertainty, title=title), out, dpi=dpi)
