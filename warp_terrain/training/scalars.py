"""Loss scalars logged without stopping the device.

Reading a CUDA loss as a Python float (``.item()``, ``.tolist()``) waits for every kernel
queued before it: a training step that logs would drain the queue that keeps the GPU busy.
``DeferredScalars`` copies the step's losses into pinned host memory with ``non_blocking=True``
and records a CUDA event behind the copy; the values are written to TensorBoard once the event
has completed, at a later log or at the end (``flush(wait=True)``), each at its own step. On the
CPU there is nothing to wait for and the values are written at once.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping

import torch


class DeferredScalars:
    """Scalars ``tag_prefix/name`` written through ``add_scalar(tag, value, step)`` once their
    device-to-host copy is done; ``latest`` holds the newest values written (for a progress bar)."""

    def __init__(self, add_scalar: Callable[[str, float, int], None], tag_prefix: str = "loss"):
        self.add_scalar = add_scalar
        self.tag_prefix = tag_prefix
        self.pending: deque[tuple[int, list[str], torch.Tensor, torch.cuda.Event | None]] = deque()
        self.latest: dict[str, float] = {}

    def push(self, step: int, values: Mapping[str, torch.Tensor]) -> None:
        """Queue the 0-d tensors ``values`` of ``step`` (copied now, on the current stream), then
        write every queued step whose copy is done."""
        if values:
            stacked = torch.stack([v.detach().reshape(()).float() for v in values.values()])
            if stacked.is_cuda:
                host = torch.empty(stacked.shape, dtype=stacked.dtype, pin_memory=True)
                host.copy_(stacked, non_blocking=True)
                event = torch.cuda.Event()
                event.record()
            else:
                host, event = stacked.clone(), None
            self.pending.append((step, list(values), host, event))
        self.flush(wait=False)

    def flush(self, wait: bool = True) -> None:
        """Write the queued steps in order: all of them (``wait``: synchronising on each copy), or
        only those whose copy is done, stopping at the first that is not."""
        while self.pending:
            step, names, host, event = self.pending[0]
            if event is not None:
                if wait:
                    event.synchronize()
                elif not event.query():
                    return
            self.pending.popleft()
            values = dict(zip(names, host.tolist()))
            for name, value in values.items():
                self.add_scalar(f"{self.tag_prefix}/{name}", value, step)
            self.latest = values
