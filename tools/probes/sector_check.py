"""Probe (docs/transfer.md): the far check on wide gaps. The scan's outer cells
(``selfcheck.outer_cells``) are replaced by its observed cells beyond the median radius inside
``K`` evenly spaced sectors of ``W`` degrees: hidden, they leave gaps several cells wide.
NAME token ``_sK_W`` (default 6_20); use ``_nokeepfar`` so that the far weight is measured.

usage: python tools/probes/sector_check.py --fills-cache outputs/fills_cache.json P_check_notta_nokeepfar=shipped ...
"""

import re

import torch
from common import run

import warp_terrain.inference.selfcheck as check

SECTORS: dict = {}


def sector_cells(mask: torch.Tensor) -> torch.Tensor:
    size = mask.shape[-1]
    axis = torch.arange(size, device=mask.device, dtype=torch.float32) - 0.5 * (size - 1)
    rows, cols = axis[:, None].expand(size, size), axis[None, :].expand(size, size)
    radius = torch.sqrt(rows**2 + cols**2).expand(mask.shape)
    angle = (torch.rad2deg(torch.atan2(rows, cols)) % 360.0).expand(mask.shape)
    observed = mask > 0
    cut = torch.nanquantile(torch.where(observed, radius, torch.nan).flatten(1), 0.5, dim=1)
    count, width = SECTORS.get("count", 6), SECTORS.get("width", 20.0)
    return observed & ((angle % (360.0 / count)) < width) & (radius > cut.view(-1, 1, 1, 1))


def settings_of(name: str) -> dict:
    m = re.search(r"_s(\d+)_(\d+)", name)
    return {"count": int(m[1]), "width": float(m[2])} if m else {}


if __name__ == "__main__":
    check.outer_cells = sector_cells  # what selfcheck.check_cells hides for the reach
    run(settings_of, SECTORS)
