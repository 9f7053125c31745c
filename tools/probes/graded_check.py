"""Probe (docs/transfer.md): a check graded by distance. Single hidden cells have
kept cells about them and measure the net where the real scans' scored cells lie, one cell from
the scan; hidden 3x3 blocks measure it one or two cells away, where shadows begin. Here both are
hidden in the one thinned pass (``_gradedP``: each about P % of the observed cells), the net's
weight taken on the single cells for cells next to the scan (chessboard distance <= 1) and on the
blocks beyond, then ramped to the whole correction far from the scan as shipped.

usage: THREADS=1 python tools/probes/graded_check.py --fills-cache outputs/fills_cache.json \
           D12_check_reach_keepfar_sigma_membrane_graded12=shipped

``CHECK_SEED=N`` in the environment draws every check's cells (the shipped one's too) from seed N
instead of ``selfcheck.CHECK_SEED``: another draw of the same check, to tell a change from the
draw's own noise.
"""

import os
import re

import torch
from common import run

import warp_terrain.inference.reconstructor as reconstructor
import warp_terrain.inference.selfcheck as check

PROBE: dict = {}
#: the shipped draw, kept before ``check.hidden_cells`` is replaced
PLAIN_HIDDEN = check.hidden_cells
BLOCK = 3
SEED = int(os.environ.get("CHECK_SEED", check.CHECK_SEED))


def parts(mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(single cells, block cells) of the check, disjoint, each about ``PROBE["share"]``."""
    share = PROBE["share"]
    generator = torch.Generator(device="cpu").manual_seed(SEED)
    draw = torch.rand(mask.shape[-2:], generator=generator)
    seeds = (torch.rand((1, 1, *mask.shape[-2:]), generator=generator) < share / BLOCK**2).to(torch.float32)
    blocks = (torch.nn.functional.max_pool2d(seeds, BLOCK, stride=1, padding=BLOCK // 2) > 0).to(mask.device) & (mask > 0)
    singles = (mask > 0) & (draw.to(mask.device) < share) & ~blocks
    return singles, blocks


def hidden_cells(mask, share=check.CHECK_SHARE, seed=None):
    if "share" not in PROBE:
        return PLAIN_HIDDEN(mask, share, SEED if seed is None else seed)
    singles, blocks = parts(mask)
    return singles | blocks


def graded(values, observed):
    """(B, 1, S, S): the single cells' weight within one cell of ``observed``, the blocks' beyond."""
    single, block = values
    distance = check.far_share(observed, 0, 8) * 8
    return torch.where(distance <= 1.0, single, block)


def checked_maps(fills, model, scan, mask, thinned, regimes, membrane, keep_far):
    if "share" not in PROBE:
        return check.checked_maps(fills, model, scan, mask, thinned, regimes, membrane, keep_far)
    n = scan.shape[0]
    fill, fill_thinned = check.checked_fills(fills, scan, mask, thinned, regimes, membrane)
    singles, blocks = parts(mask)
    outer = regimes.outer if regimes.outer is not None else torch.zeros_like(singles)
    values = tuple(check.correction_weight(model[n:], fill_thinned, scan, cells & ~outer) for cells in (singles, blocks))
    away = None if regimes.outer is None else torch.ones_like(values[0])
    if not keep_far and away is not None:
        away = check.correction_weight(model[n:], fill_thinned, scan, regimes.outer)
    maps = []
    for f, m, observed in ((fill, model[:n], mask), (fill_thinned, model[n:], thinned)):
        maps.append(regimes.apply((graded(values, observed), away), f, m, observed))
    return tuple(maps)


def settings_of(name: str) -> dict:
    m = re.search(r"_graded(\d+)", name)
    return {"share": int(m[1]) / 100.0} if m else {}


if __name__ == "__main__":
    check.hidden_cells = hidden_cells  # what selfcheck.check_cells draws
    reconstructor.checked_maps = checked_maps
    run(settings_of, PROBE)
