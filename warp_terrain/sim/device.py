"""Device selection and the Warp <-> torch hand-off.

``device`` is ``"cpu"``, ``"cuda"`` (or ``"cuda:N"``) or ``None``: the device named by the
environment variable ``WARP_TERRAIN_DEVICE`` if set, else CUDA when available, else CPU (the test
suite sets ``WARP_TERRAIN_DEVICE=cpu``, so it runs the same on a GPU machine; tests marked
``gpu`` ask for CUDA by name).
Warp arrays are handed to torch with ``wp.to_torch`` and taken from torch with
``wp.from_torch``: both share memory, nothing is copied. On CUDA the launches that fill them run
on torch's current stream (``torch_stream``), so what torch queues next on that stream sees
their results, with no host sync and no reliance on either library's default stream.
"""

from __future__ import annotations

import os
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import torch
import warp as wp

#: The environment variable that names the default device (``cpu``, ``cuda``, ``cuda:N``).
DEVICE_ENV = "WARP_TERRAIN_DEVICE"


#: What Warp's native library prints when a machine has no NVIDIA driver: nothing is wrong on a
#: CPU machine, so it is not shown unless ``WARP_TERRAIN_VERBOSE`` is set.
NO_DRIVER = "Could not find or load the NVIDIA CUDA driver"
_warp_ready = False


def init_warp() -> None:
    """``wp.init()``, without the native library's no-driver warning on a CPU-only machine
    (everything else it prints still reaches stderr). Idempotent."""
    global _warp_ready
    if _warp_ready or os.environ.get("WARP_TERRAIN_VERBOSE"):
        wp.init()
        _warp_ready = True
        return
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as caught:
        os.dup2(caught.fileno(), 2)
        try:
            wp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        caught.seek(0)
        text = caught.read().decode(errors="replace")
    _warp_ready = True
    for line in text.splitlines():
        if NO_DRIVER not in line:
            print(line, file=sys.stderr)


def resolve_device(device: str | torch.device | None = None) -> str:
    """The Warp device name (``"cpu"`` or ``"cuda:N"``) for a user's ``device`` argument."""
    init_warp()
    if device is None:
        device = os.environ.get(DEVICE_ENV) or None
    if device is None:
        return "cuda:0" if wp.is_cuda_available() and torch.cuda.is_available() else "cpu"
    name = str(device)
    if name == "cpu":
        return "cpu"
    if name.startswith("cuda"):
        if not wp.is_cuda_available():
            raise ValueError(f"device={name!r}: CUDA is not available on this machine; use 'cpu' or None")
        return "cuda:0" if name == "cuda" else name
    raise ValueError(f"device={name!r}: expected 'cpu', 'cuda', 'cuda:N' or None")


def to_warp(x, dtype, device: str) -> wp.array:
    """A Warp view of a torch tensor (zero-copy when device and dtype match) or a copy of array data."""
    if isinstance(x, torch.Tensor):
        t = x.detach()
        if t.device != torch.device(device):
            t = t.to(device)
        return wp.from_torch(t.contiguous().to(torch.float32), dtype=dtype)
    return wp.array(np.ascontiguousarray(x, dtype=np.float32), dtype=dtype, device=device)


@contextmanager
def torch_stream(device: str) -> Iterator[None]:
    """Inside, Warp launches and allocations on CUDA ``device`` go to torch's current stream of
    that device (``wp.stream_from_torch``; the stream first waits for Warp's previous one). One
    stream for both libraries: tensors handed over zero-copy are ordered with what torch does
    next, under a non-default torch stream or graph capture too. Nothing changes on the CPU."""
    if not str(device).startswith("cuda"):
        yield
        return
    with wp.ScopedStream(wp.stream_from_torch(torch.cuda.current_stream(torch.device(device)))):
        yield
