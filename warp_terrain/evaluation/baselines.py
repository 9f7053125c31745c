"""Classical fills of elevation maps from the observed cells (the baselines a model must beat)."""

from __future__ import annotations

import numpy as np
import torch
from scipy import ndimage


def nearest_fill(scan: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Each unobserved cell takes the height of the nearest observed cell (Euclidean, in cells).

    ``scan``/``mask``: ``(B, 1, H, W)``. Maps with no observed cell come back as zeros.
    Uses ``scipy.ndimage.distance_transform_edt``'s nearest-feature indices.
    """
    s = scan.detach().cpu().numpy()
    m = mask.detach().cpu().numpy() > 0
    out = np.zeros_like(s)
    for b in range(s.shape[0]):
        if not m[b, 0].any():
            continue
        _, (ii, jj) = ndimage.distance_transform_edt(~m[b, 0], return_indices=True)
        out[b, 0] = s[b, 0][ii, jj]
    return torch.from_numpy(out).to(scan.device)
