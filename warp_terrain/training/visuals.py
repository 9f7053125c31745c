"""Pictures of the validation maps: scan | mask | prediction | ground truth | error.

``map_grid`` is a bare image grid for TensorBoard (logged every ``train.image_every`` steps);
``validation_figure`` is the labelled figure saved as ``images/validation.png`` at the end of
a run: panel titles, axes in metres in the sensor frame and a colour bar with units per panel.
"""

from __future__ import annotations

import numpy as np
import torch
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import BoundaryNorm, ListedColormap, Normalize
from matplotlib.figure import Figure

from ..core.geometry import MapGeometry

PANELS = ("scan", "mask", "prediction", "target", "error")
#: ``validation_figure``'s panel titles, left to right, and each panel's colour-bar label.
VALIDATION_TITLES = ("scan", "mask", "prediction", "ground truth", "|error|")
VALIDATION_COLORBARS = ("z (m)", "mask (1 = observed)", "z (m)", "z (m)", "|error| (m)")


def _colour(x: np.ndarray, lo: float, hi: float, cmap: str, hidden: np.ndarray | None = None) -> np.ndarray:
    rgb = colormaps[cmap](np.clip((x - lo) / max(hi - lo, 1e-6), 0.0, 1.0))[..., :3]
    if hidden is not None:
        rgb[hidden] = 0.0  # unobserved cells of the scan are black
    return rgb


def _first(rows: int, *maps: torch.Tensor) -> list[np.ndarray]:
    """The first ``rows`` maps of each ``(N, 1, S, S)`` tensor as ``(n, S, S)`` float arrays."""
    n = min(rows, maps[0].shape[0])
    return [x[:n, 0].detach().float().cpu().numpy() for x in maps]


def map_grid(scan: torch.Tensor, mask: torch.Tensor, prediction: torch.Tensor, target: torch.Tensor, rows: int = 4) -> np.ndarray:
    """An ``(3, rows*S, 5*S)`` float image in [0, 1]: one sample per row, one panel per column.

    Heights share one colour scale per row (the ground truth's range); the error panel shows
    ``|prediction - target|`` from 0 to 1 m.
    """
    s, m, p, t = _first(rows, scan, mask, prediction, target)
    lines = []
    for b in range(s.shape[0]):
        lo, hi = float(t[b].min()), float(t[b].max())
        hidden = m[b] <= 0
        panels = [
            _colour(s[b], lo, hi, "viridis", hidden),
            _colour(m[b], 0.0, 1.0, "gray"),
            _colour(p[b], lo, hi, "viridis"),
            _colour(t[b], lo, hi, "viridis"),
            _colour(np.abs(p[b] - t[b]), 0.0, 1.0, "magma"),
        ]
        lines.append(np.concatenate(panels, axis=1))
    grid = np.concatenate(lines, axis=0)
    return np.ascontiguousarray(grid.transpose(2, 0, 1), dtype=np.float32)


def validation_figure(scan: torch.Tensor, mask: torch.Tensor, prediction: torch.Tensor, target: torch.Tensor, map_cell: float,
                      rows: int = 4, step: int | None = None) -> Figure:
    """A matplotlib figure of the first ``rows`` validation maps (``(N, 1, S, S)`` tensors of
    ``map_cell``-metre cells): one map per row, the panels ``VALIDATION_TITLES`` with x and y
    in metres (sensor frame, x right, y up) and a colour bar labelled ``VALIDATION_COLORBARS``.

    Scan, prediction and ground truth share one height scale per row (the ground truth's range);
    the scan's unobserved cells are black. ``step`` goes into the title.
    """
    s, m, p, t = _first(rows, scan, mask, prediction, target)
    n, size = s.shape[0], s.shape[-1]
    half = MapGeometry(size, float(map_cell)).half_extent
    extent = [-half, half, -half, half]
    fig = Figure(figsize=(3.3 * len(VALIDATION_TITLES), 2.8 * n + 0.4), layout="constrained")
    FigureCanvasAgg(fig)
    axes = np.asarray(fig.subplots(n, len(VALIDATION_TITLES), squeeze=False))
    heights = colormaps["viridis"].with_extremes(bad="black")
    binary = dict(cmap=ListedColormap(["0.12", "0.95"]), norm=BoundaryNorm([-0.5, 0.5, 1.5], 2))
    for b in range(n):
        lo, hi = float(t[b].min()), float(t[b].max())
        z = Normalize(lo, hi if hi - lo > 1e-6 else lo + 1e-3)
        error = np.abs(p[b] - t[b])
        panels = [
            dict(data=np.ma.masked_where(m[b] <= 0, s[b]), cmap=heights, norm=z),
            dict(data=(m[b] > 0).astype(np.float32), **binary),
            dict(data=p[b], cmap="viridis", norm=z),
            dict(data=t[b], cmap="viridis", norm=z),
            dict(data=error, cmap="magma", norm=Normalize(0.0, max(float(error.max()), 1e-3))),
        ]
        for ax, panel, title, label in zip(axes[b], panels, VALIDATION_TITLES, VALIDATION_COLORBARS):
            data = panel.pop("data")
            im = ax.imshow(data.T, origin="lower", extent=extent, **panel)
            ax.set_title(title)
            ax.set_xlabel("x (m)")
            ax.set_ylabel("y (m)")
            fig.colorbar(im, ax=ax, label=label, **({"ticks": [0, 1]} if title == "mask" else {}))
    when = f" after step {step}" if step is not None else ""
    fig.suptitle(f"validation maps{when} (first {n}, one per row; unobserved scan cells black)")
    return fig
