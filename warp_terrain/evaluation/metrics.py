"""Error metrics in metres over chosen cells of elevation maps, and obstacle scores.

All functions take ``(B, 1, S, S)`` torch tensors (any device; computed in float32/float64 on
that device) and return Python floats, pooled over every selected cell of the whole batch (a
large map counts as much as its cells, not as one sample). NaN when nothing is selected.

Which cells:

- **unobserved**: ``mask == 0``, what a fill has to invent;
- **observed**: ``mask > 0``, where a fill keeps (or a model may denoise) the measurement;
- **in range**: every cell whose centre lies within ``min(max_range, S * cell / 2)`` metres of
  the map's centre (the sensor). With every preset's max range (>= 100 m) far beyond the 30 m
  map, that is the map's inscribed disc (pi/4 of the cells): the corners are left out because
  they lie in range in some directions only, and a disc is unchanged by the flips and
  90-degree rotations the data may be augmented with. See :func:`range_cells`.

Obstacles are judged against the *bare ground*: the same terrain without its obstacles. The
evaluation gets it exactly by generating each test sample again with every obstacle count set
to zero (obstacles draw from their own random stream, so the relief, the sensor height and the
augmentation are unchanged; ``tests/test_evaluation.py`` checks this).

- **obstacle IoU** (positive obstacles: cylinders, boxes, rocks): the footprint is the cells
  whose height exceeds the bare ground by more than ``threshold`` (0.3 m); the same test on
  the prediction gives the predicted footprint; IoU = |both| / |either|, pooled over the batch.
- **pit recall** (negative obstacles: pits, ditches): pit cells are those whose true height is
  more than ``threshold`` below the bare ground; a pit cell counts as found where the
  prediction is more than ``threshold / 2`` below the bare ground.

A model with an uncertainty head also gives each cell a standard deviation ``sigma`` (m).
:func:`calibration` says whether to trust it: the share of cells whose error lies within
``sigma`` and within ``2 sigma`` (a calibrated Gaussian: 68.3 % and 95.4 %), and the RMS of
``sigma`` next to the RMSE it should match.
"""

from __future__ import annotations

import math

import torch

__all__ = [
    "OBSTACLE_THRESHOLD",
    "calibration",
    "error_metrics",
    "masked_mae",
    "masked_rmse",
    "obstacle_iou",
    "pit_recall",
    "range_cells",
]

#: Height (metres) above the bare ground that makes a cell part of an obstacle's footprint,
#: or below it that makes it part of a pit.
OBSTACLE_THRESHOLD = 0.3


def _check_same(prediction: torch.Tensor, target: torch.Tensor, other: torch.Tensor, other_name: str) -> None:
    if prediction.shape != target.shape or other.shape != target.shape:
        raise ValueError(
            f"prediction {tuple(prediction.shape)}, target {tuple(target.shape)} and {other_name} {tuple(other.shape)} must match"
        )


def _selected_errors(prediction: torch.Tensor, target: torch.Tensor, cells: torch.Tensor) -> torch.Tensor | None:
    """float64 errors on the cells where ``cells`` is true; None when no cell is selected."""
    _check_same(prediction, target, cells, "cells")
    cells = cells.bool()
    if not bool(cells.any()):
        return None
    return (prediction.double() - target.double())[cells]


def masked_rmse(prediction: torch.Tensor, target: torch.Tensor, cells: torch.Tensor) -> float:
    """Root-mean-square error (metres) over the cells where ``cells`` is true, pooled over the batch.

    NaN when no cell is selected.
    """
    err = _selected_errors(prediction, target, cells)
    return float("nan") if err is None else float(torch.sqrt((err * err).mean()))


def masked_mae(prediction: torch.Tensor, target: torch.Tensor, cells: torch.Tensor) -> float:
    """Mean absolute error (metres) over the cells where ``cells`` is true, pooled over the batch.

    NaN when no cell is selected.
    """
    err = _selected_errors(prediction, target, cells)
    return float("nan") if err is None else float(err.abs().mean())


def range_cells(map_size: int, map_cell: float, max_range: float = math.inf, device=None) -> torch.Tensor:
    """``(1, 1, S, S)`` bool: cells whose centre lies within ``min(max_range, S * map_cell / 2)``
    metres of the map's centre (cell (p, q) is centred at ``((p - (S-1)/2) * map_cell,
    (q - (S-1)/2) * map_cell)``). Broadcast it against a batch with ``expand_as``."""
    if not (isinstance(map_size, int) and map_size >= 1):
        raise ValueError(f"map_size={map_size!r}: must be an integer >= 1")
    if not (map_cell > 0 and math.isfinite(map_cell)):
        raise ValueError(f"map_cell={map_cell!r}: must be a finite number > 0")
    if not max_range > 0:
        raise ValueError(f"max_range={max_range!r}: must be > 0")
    radius = min(float(max_range), 0.5 * map_size * map_cell)
    c = (torch.arange(map_size, dtype=torch.float64, device=device) - 0.5 * (map_size - 1)) * map_cell
    inside = c[:, None] ** 2 + c[None, :] ** 2 <= radius * radius * (1 + 1e-12)
    return inside[None, None]


def obstacle_iou(prediction: torch.Tensor, target: torch.Tensor, ground: torch.Tensor, threshold: float = OBSTACLE_THRESHOLD) -> float:
    """IoU of positive-obstacle footprints: cells more than ``threshold`` metres above the bare
    ``ground`` in ``target`` versus in ``prediction``, pooled over the batch. NaN if neither has any."""
    _check_same(prediction, target, ground, "ground")
    truth = (target - ground) > threshold
    guess = (prediction - ground) > threshold
    union = int((truth | guess).sum())
    if union == 0:
        return float("nan")
    return int((truth & guess).sum()) / union


def pit_recall(prediction: torch.Tensor, target: torch.Tensor, ground: torch.Tensor, threshold: float = OBSTACLE_THRESHOLD) -> float:
    """Share of pit cells (``target`` more than ``threshold`` below the bare ``ground``) that the
    prediction puts more than ``threshold / 2`` below the ground. NaN without pit cells."""
    _check_same(prediction, target, ground, "ground")
    pits = (ground - target) > threshold
    n = int(pits.sum())
    if n == 0:
        return float("nan")
    found = (ground - prediction) > 0.5 * threshold
    return int((pits & found).sum()) / n


def error_metrics(prediction: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, in_range: torch.Tensor | None = None) -> dict[str, float]:
    """RMSE and MAE (metres) on unobserved, observed and in-range cells:
    ``{"rmse_unobserved", "mae_unobserved", "rmse_observed", "mae_observed", "rmse_in_range",
    "mae_in_range"}``. ``in_range``: a mask broadcastable to the maps (:func:`range_cells`);
    None: every cell."""
    _check_same(prediction, target, mask, "mask")
    observed = mask > 0
    cells = {"unobserved": ~observed, "observed": observed}
    cells["in_range"] = torch.ones_like(observed) if in_range is None else in_range.to(observed.device).bool().expand_as(observed)
    out = {}
    for name, sel in cells.items():
        out[f"rmse_{name}"] = masked_rmse(prediction, target, sel)
        out[f"mae_{name}"] = masked_mae(prediction, target, sel)
    return out


def calibration(prediction: torch.Tensor, sigma: torch.Tensor, target: torch.Tensor, cells: torch.Tensor) -> dict[str, float]:
    """How well a predicted standard deviation ``sigma`` (m) describes the errors on ``cells``:
    ``{"within_1sigma", "within_2sigma", "rms_sigma"}`` (shares of the cells whose
    ``|prediction - target|`` is at most ``sigma`` / ``2 sigma``, and ``sqrt(mean sigma^2)``
    in metres). NaN when no cell is selected."""
    _check_same(prediction, target, sigma, "sigma")
    errors = _selected_errors(prediction, target, cells)
    if errors is None:
        return {"within_1sigma": math.nan, "within_2sigma": math.nan, "rms_sigma": math.nan}
    s = sigma.double()[cells.bool()]
    return {
        "within_1sigma": float((errors.abs() <= s).double().mean()),
        "within_2sigma": float((errors.abs() <= 2.0 * s).double().mean()),
        "rms_sigma": float(s.square().mean().sqrt()),
    }
