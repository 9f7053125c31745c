"""Every seed range in one place: training, validation, figures, dataset shards and test sets.

``generate_batch`` takes 31-bit seeds. Training batch ``step`` of rank ``rank`` is
``batch_seed(seed, rank, step)`` in ``[0, 2**30)``, so any batch can be regenerated from its
coordinates (a resumed run sees exactly the batches an uninterrupted one would; ranks and
workers never repeat each other). Validation chunks are ``2**30 + i``; figures use one seed
above the validation set's; the evaluation test sets start at ``2**31 - 2**24``. The ranges
never meet.
"""

from __future__ import annotations

import hashlib

#: First validation seed; training seeds lie below it.
VALIDATION_SEED_BASE = 1 << 30
#: A validation-range seed the validation set does not use (the paper-style figures of a run).
FIGURE_SEED = VALIDATION_SEED_BASE + (1 << 20)
#: First test seed: the top 2**24 of the 31-bit seeds.
TEST_SEED_BASE = 2**31 - 2**24


def batch_seed(seed: int, rank: int, step: int) -> int:
    """The generator seed of training batch ``step`` on ``rank`` (in ``[0, 2**30)``)."""
    digest = hashlib.blake2b(f"{seed}/{rank}/{step}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "little") % VALIDATION_SEED_BASE


def validation_seed(index: int) -> int:
    """The generator seed of validation chunk ``index`` (never a training seed)."""
    return VALIDATION_SEED_BASE + index


def shard_seed(seed: int, k: int) -> int:
    """The ``generate_batch`` seed of dataset shard ``k``: the training stream's ``batch_seed(seed, 0, k)``."""
    return batch_seed(int(seed), 0, int(k))
