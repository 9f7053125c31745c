"""Data-parallel training across processes started by ``torchrun``.

``torchrun --nproc_per_node=N train.py ...`` sets ``RANK``, ``LOCAL_RANK`` and ``WORLD_SIZE``;
each rank then generates its own stream (batch seeds depend on the rank, so ranks never repeat
each other) on its own device, and gradients are averaged across ranks every step. The process
group uses NCCL on CUDA and gloo on the CPU. Rank 0 alone validates, logs and checkpoints.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist


@dataclass(frozen=True)
class Ranks:
    rank: int = 0
    world: int = 1
    local_rank: int = 0

    @property
    def main(self) -> bool:
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.world > 1


def init_ranks(device: str) -> tuple[Ranks, str]:
    """Join the process group if launched by torchrun; returns the ranks and this rank's device."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return Ranks(), device
    rank, local = int(os.environ["RANK"]), int(os.environ.get("LOCAL_RANK", "0"))
    if device.startswith("cuda"):
        torch.cuda.set_device(local)
        device = f"cuda:{local}"
    if not dist.is_initialized():
        dist.init_process_group("nccl" if device.startswith("cuda") else "gloo")
    return Ranks(rank, world, local), device


def close_ranks(ranks: Ranks) -> None:
    if ranks.distributed and dist.is_initialized():
        dist.barrier()
        dist.destroy_process_group()


class NullWriter:
    """What non-main ranks log to: nothing."""

    def __getattr__(self, name):
        return lambda *args, **kwargs: None
