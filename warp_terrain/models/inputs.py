"""What a generator sees: the scan image, or the scan and its observation mask."""

from __future__ import annotations

import torch


def model_input(scan: torch.Tensor, mask: torch.Tensor, in_channels: int) -> torch.Tensor:
    """The network's condition, ``(B, in_channels, S, S)``: the scan (1) or scan and mask (2)."""
    if in_channels == 1:
        return scan
    return torch.cat([scan, mask], dim=1)
