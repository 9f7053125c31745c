"""Training: the loop, its configuration, checkpoints, ranks and TensorBoard logging."""

from .config import RunConfig, TrainConfig
from .loop import train

__all__ = ["RunConfig", "TrainConfig", "train"]
