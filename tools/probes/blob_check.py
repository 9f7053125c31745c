"""Probe (docs/transfer.md): the self-check hiding blobs of observed cells instead
of single cells. A single hidden cell has kept cells all about it, where the net's correction
matters least; the shadows the net fills lie cells away from the scan. NAME token ``_blobN``:
the check's cells are N x N blocks (seeds drawn at share / N^2, dilated, kept where observed),
about the same share of the observed cells; without it the shipped check.

usage: THREADS=1 python tools/probes/blob_check.py --fills-cache outputs/fills_cache.json \
           B3_check_reach_keepfar_sigma_membrane_blob3=shipped
"""

import re

import torch
from common import run

import warp_terrain.inference.selfcheck as check

PROBE: dict = {}
#: the shipped draw, kept before ``check.hidden_cells`` is replaced
PLAIN_HIDDEN = check.hidden_cells


def hidden_cells(mask: torch.Tensor, share: float = check.CHECK_SHARE, seed: int = check.CHECK_SEED) -> torch.Tensor:
    size = PROBE.get("blob")
    if not size:
        return PLAIN_HIDDEN(mask, share, seed)
    generator = torch.Generator(device="cpu").manual_seed(seed)
    seeds = (torch.rand((1, 1, *mask.shape[-2:]), generator=generator) < share / size**2).to(torch.float32)
    blobs = torch.nn.functional.max_pool2d(seeds, size, stride=1, padding=size // 2)[..., : mask.shape[-2], : mask.shape[-1]]
    return (mask > 0) & (blobs.to(mask.device) > 0)


def settings_of(name: str) -> dict:
    m = re.search(r"_blob(\d+)", name)
    return {"blob": int(m[1])} if m else {}


if __name__ == "__main__":
    check.hidden_cells = hidden_cells  # what selfcheck.check_cells draws
    run(settings_of, PROBE)
