"""Probe (docs/transfer.md): the net's correction on unobserved cells ramped from
nothing at an observed cell to whole ``N`` cells away (``clamp(d / N, 0, 1)``, d the chessboard
distance), with or without the self-check. NAME token ``_gN`` (no token: no gate).

usage: python tools/probes/near_gate.py --fills-cache outputs/fills_cache.json S_notta_g3=shipped ...
"""

import re

import torch
from common import run

from warp_terrain.inference.selfcheck import far_share
from warp_terrain.models import fill as fill_module

GATE: dict = {}
plain_forward = fill_module.FillResidualGenerator.forward


def gated_forward(self, condition, fill=None):
    out = plain_forward(self, condition, fill)
    cells = GATE.get("cells", 0)
    if cells <= 0:
        return out
    scan, mask = condition[:, :1], condition[:, 1:2]
    base = self.base_fill(scan, mask) if fill is None else fill
    gate = mask + (1.0 - mask) * far_share(mask, near=0, far=cells)
    height = base + gate * (out[:, :1] - base)
    return torch.cat([height, out[:, 1:]], dim=1) if out.shape[1] > 1 else height


def settings_of(name: str) -> dict:
    m = re.search(r"_g(\d+)", name)
    return {"cells": int(m[1])} if m else {}


if __name__ == "__main__":
    fill_module.FillResidualGenerator.forward = gated_forward
    run(settings_of, GATE)
