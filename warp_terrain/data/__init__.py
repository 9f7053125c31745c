"""Training data: the endless stream, its seeds, and datasets on disk.

- ``seeds``: every seed range (training, validation, figures, shards, test sets)
- ``stream``: ``PairStream`` and ``training_batches``, the live stream (worker processes on a CPU)
- ``disk``: ``write_dataset`` and ``DiskPairs``, the same pairs as files
"""

from .disk import DatasetError, DiskPairs, write_dataset
from .seeds import batch_seed, shard_seed, validation_seed
from .stream import PairStream, make_pair, training_batches, validation_set

__all__ = ["DatasetError", "DiskPairs", "PairStream", "batch_seed", "make_pair", "shard_seed", "training_batches",
           "validation_seed", "validation_set", "write_dataset"]
