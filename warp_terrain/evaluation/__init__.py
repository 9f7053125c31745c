"""Evaluation: metrics in metres, classical fills to beat, and fixed test sets to score them on.

Modules:

- ``metrics``: RMSE/MAE on masks, the in-range disc, obstacle IoU, pit recall, calibration;
- ``baselines``: the classical fills (``BASELINES``), each a predictor ``f(scan, mask)``;
- ``testsets``: the fixed test sets (``make_eval_set``, ``EvalSet``) and their seeds;
- ``scoring``: ``evaluate`` (``warp-terrain evaluate``), every predictor on every test set;
- ``report``: the results as text or Markdown tables (``format_table``, ``format_markdown``)
  and strict JSON (``json_ready``);
- ``robustness``: sets outside the training ranges and real terrain (``--robustness``);
- ``calibrate``: the sigma scale of a model's uncertainty head.

The figures of an evaluation live above this layer, in ``warp_terrain.plots.evaluation``.
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
from .report import format_markdown, format_table, json_ready
from .scoring import PredictorFn, evaluate, run_predictor, score
from .testsets import (
    CHUNK,
    DEFAULT_NOISE,
    DEFAULT_SETTINGS,
    DEFAULT_SIZE,
    QUICK_SIZE,
    TEST_SEED_BASE,
    EvalSet,
    bare_config,
    eval_seeds,
    make_eval_set,
    setting_config,
    setting_name,
)

__all__ = [
    "BASELINES",
    "CHUNK",
    "DEFAULT_NOISE",
    "DEFAULT_SETTINGS",
    "DEFAULT_SIZE",
    "QUICK_SIZE",
    "TEST_SEED_BASE",
    "EvalSet",
    "PredictorFn",
    "bare_config",
    "biharmonic_fill",
    "error_metrics",
    "eval_seeds",
    "evaluate",
    "format_markdown",
    "format_table",
    "json_ready",
    "linear_fill",
    "make_eval_set",
    "masked_mae",
    "masked_rmse",
    "navier_stokes_fill",
    "nearest_fill",
    "obstacle_iou",
    "pit_recall",
    "plane_fill",
    "range_cells",
    "run_predictor",
    "score",
    "setting_config",
    "setting_name",
    "telea_fill",
]
