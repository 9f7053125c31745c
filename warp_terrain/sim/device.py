"""Device selection and the Warp <-> torch hand-off.

``device`` is ``"cpu"``, ``"cuda"`` (or ``"cuda:N"``) or ``None``: the device named by the
environment variable ``WARP_TERRAIN_DEVICE`` if set, else CUDA when available, else CPU (the test
suite sets ``WARP_TERRAIN_DEVICE=cpu``, so it runs the same on a GPU machine; tests marked
``gpu`` ask for CUDA by name).
Warp arrays are handed to torch with ``wp.to_torch`` and taken from torch with
``wp.from_torch``: both share memory, nothing is copied.
"""

from __future__ import annotations

import os

import numpy as np
import torch
import warp as wp

#: The environment variable that names the default device (``cpu``, ``cuda``, ``cuda:N``).
DEVICE_ENV = "WARP_TERRAIN_DEVICE"


def resolve_device(device: str | torch.device | None = None) -> str:
    """The Warp device name (``"cpu"`` or ``"cuda:N"``) for a user's ``device`` argument."""
    wp.init()
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
