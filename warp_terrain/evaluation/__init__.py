"""Evaluation: metrics in metres, classical fills to beat, and fixed test sets to score them on.

The test sets and ``evaluate`` (``warp-terrain evaluate``) live in
``warp_terrain.evaluation.evaluate``; import them from there (the training loop imports this
package for its metrics and need not load them).
"""

from .baselines import (
    BASELINES,
    biharmonic_fill,
    linear_fill,
    navier_stokes_fill,
    nearest_fill,
    plane_fill,
    telea_fill,
)
from .metrics import error_metrics, masked_mae, masked_rmse, obstacle_iou, pit_recall, range_cells

__all__ = [
    "BASELINES",
    "biharmonic_fill",
    "error_metrics",
    "linear_fill",
    "masked_mae",
    "masked_rmse",
    "navier_stokes_fill",
    "nearest_fill",
    "obstacle_iou",
    "pit_recall",
    "plane_fill",
    "range_cells",
    "telea_fill",
]
