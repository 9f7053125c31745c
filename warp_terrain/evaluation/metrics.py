"""Error metrics in metres over chosen cells of elevation maps."""

from __future__ import annotations

import torch


def masked_rmse(prediction: torch.Tensor, target: torch.Tensor, cells: torch.Tensor) -> float:
    """Root-mean-square error (metres) over the cells where ``cells`` is true, pooled over the batch.

    NaN when no cell is selected.
    """
    if prediction.shape != target.shape or cells.shape != target.shape:
        raise ValueError(f"prediction {tuple(prediction.shape)}, target {tuple(target.shape)} and cells {tuple(cells.shape)} must match")
    cells = cells.bool()
    n = int(cells.sum())
    if n == 0:
        return float("nan")
    err = (prediction.float() - target.float())[cells]
    return float(torch.sqrt((err * err).mean()))
