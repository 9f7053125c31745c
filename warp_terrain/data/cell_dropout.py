"""Observed cells hidden from a training input, as the self-check hides them at inference.

The self-check (``inference/selfcheck.py``) predicts every map again with a fifth of its
observed cells hidden at random and weighs the net's correction by how it does there: single
holes inside a ring of returns, which a simulated scan never has (a ring's cells are observed
side by side). ``drop_observed_cells`` makes such holes in training inputs: each map loses a
share of its observed cells drawn uniformly in ``[0, share]``; the cells become unobserved, so
the loss scores the net on them against the truth like any other unobserved cell.
"""

from __future__ import annotations

import torch


def drop_observed_cells(scan: torch.Tensor, mask: torch.Tensor, share: float, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``(scan, mask)`` (B, 1, H, W) with about ``u_b`` of map ``b``'s observed cells hidden,
    ``u_b`` uniform in ``[0, share]``, all drawn from ``seed`` (a CPU generator: the same on any
    device); the hidden cells' heights set to 0, as an unobserved cell's are. ``share = 0``
    returns the inputs as they are."""
    if isinstance(share, bool) or not isinstance(share, (int, float)) or not 0.0 <= share < 1.0:
        raise ValueError(f"share={share!r}: must be a number in [0, 1)")
    if share == 0:
        return scan, mask
    generator = torch.Generator(device="cpu").manual_seed(int(seed))
    rates = torch.rand(mask.shape[0], 1, 1, 1, generator=generator) * share
    draw = torch.rand(mask.shape, generator=generator)
    keep = ((draw >= rates) | (mask.cpu() <= 0)).to(device=mask.device, dtype=mask.dtype)
    return scan * keep, mask * keep
