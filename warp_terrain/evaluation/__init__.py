"""Evaluation: metrics in metres and classical fills to beat."""

from .baselines import nearest_fill
from .metrics import masked_rmse

__all__ = ["masked_rmse", "nearest_fill"]
