"""Image grids of elevation maps: scan | mask | prediction | ground truth | error."""

from __future__ import annotations

import numpy as np
import torch
from matplotlib import colormaps

PANELS = ("scan", "mask", "prediction", "target", "error")


def _colour(x: np.ndarray, lo: float, hi: float, cmap: str, hidden: np.ndarray | None = None) -> np.ndarray:
    rgb = colormaps[cmap](np.clip((x - lo) / max(hi - lo, 1e-6), 0.0, 1.0))[..., :3]
    if hidden is not None:
        rgb[hidden] = 0.0  # unobserved cells of the scan are black
    return rgb


def map_grid(scan: torch.Tensor, mask: torch.Tensor, prediction: torch.Tensor, target: torch.Tensor, rows: int = 4) -> np.ndarray:
    """An ``(3, rows*S, 5*S)`` float image in [0, 1]: one sample per row, one panel per column.

    Heights share one colour scale per row (the ground truth's range); the error panel shows
    ``|prediction - target|`` from 0 to 1 m.
    """
    n = min(rows, scan.shape[0])
    s, m, p, t = (x[:n, 0].detach().float().cpu().numpy() for x in (scan, mask, prediction, target))
    lines = []
    for b in range(n):
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
