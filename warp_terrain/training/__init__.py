"""Training: the endless stream, the generic loop, checkpoints and TensorBoard logging."""

from .config import TrainConfig
from .loop import train
from .stream import PairStream, batch_seed, training_batches, validation_set

__all__ = ["PairStream", "TrainConfig", "batch_seed", "train", "training_batches", "validation_set"]
