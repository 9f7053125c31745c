"""A scan's own measurement noise, estimated from the scan alone.

Pure torch and exportable to ONNX (a sort and a gather, no ``nanmedian``), so a generator may use
it inside its forward (``model.observed_bound_noise``) and the self-check outside it
(``inference.selfcheck``) on the same footing.
"""

from __future__ import annotations

import torch

#: A Gaussian's standard deviation over its median absolute deviation.
NOISE_MAD = 1.4826


def lower_median(values: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """(B,) the median of each row's ``valid`` entries of ``values`` (B, N), the lower of the two
    middle values for an even count (as ``torch.nanmedian``); 0 for a row with none. A sort with
    the invalid entries pushed past the valid ones, and a gather: exportable to ONNX."""
    big = torch.finfo(values.dtype).max
    ordered = torch.sort(torch.where(valid, values, torch.full_like(values, big)), dim=1).values
    count = valid.sum(dim=1)
    index = (count - 1).clamp_min(0) // 2
    middle = ordered.gather(1, index.view(-1, 1)).view(-1)
    return torch.where(count > 0, middle, torch.zeros_like(middle))


def scan_noise(scan: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(B, 1, 1, 1) metres: each map's per-cell measurement noise, estimated from the scan alone.

    The second difference ``z[i-1] - 2 z[i] + z[i+1]`` of three observed cells in a row or a
    column is zero on any plane, so on ground smooth at the cell's scale it is the noise's own:
    for independent noise of standard deviation ``s`` its variance is ``6 s^2``. The estimate is
    the robust one, ``1.4826 median|second difference| / sqrt(6)`` over both directions (the
    median shrugs off the steps of walls and pit edges); 0 for a map with no three observed
    cells in a line. What it cannot see is error that neighbouring cells share (a bias of the
    projection along a ring): on clean simulated scans of the real suite's terrain and of the
    synthetic settings it is 0.2-0.6 of the scan's true error, so it errs low; ground rough at
    the cell's own scale adds its curvature."""
    observed = mask > 0
    diffs, valid = [], []
    for dim in (2, 3):
        length = scan.shape[dim] - 2
        if length < 1:
            continue
        a, b, c = (scan.narrow(dim, i, length) for i in range(3))
        valid.append((observed.narrow(dim, 0, length) & observed.narrow(dim, 1, length) & observed.narrow(dim, 2, length)).flatten(1))
        diffs.append((a - 2.0 * b + c).abs().float().flatten(1))
    if not diffs:
        return scan.new_zeros(scan.shape[0], 1, 1, 1)
    median = lower_median(torch.cat(diffs, dim=1), torch.cat(valid, dim=1))
    return (NOISE_MAD * median / 6.0**0.5).view(-1, 1, 1, 1).to(scan.dtype)
