"""Device selection and the Warp <-> torch hand-off.

``device`` is ``"cpu"``, ``"cuda"`` (or ``"cuda:N"``) or ``None`` (CUDA when available, else CPU).
Warp arrays are handed to torch with ``wp.to_torch`` and taken from torch with
``wp.from_torch``: both share memory, nothing is copied.
"""

from __future__ import annotations

import numpy as np
import torch
import warp as wp


def resolve_device(device: str | torch.device | None = None) -> str:
    """The Warp device name (``"cpu"`` or ``"cuda:N"``) for a user's ``device`` argument."""
    wp.init()
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
