"""Probe (docs/transfer.md, stop 42): keep the net's large corrections whole unless the check
refutes them.

The check weighs the net's correction on hidden observed cells, where the ground is open and
the correction is a few centimetres; where the net digs a pit (decimetres below the fill, 2-7
cells from the scan) the check has no cell, and its map-wide weight, set by the open ground,
switches the pit off (stop 32: 97 % of the pits' error lies inside them). Here a cell whose
correction goes below the fill by more than ``T`` cm (``_digT``; ``_bigT``: either way) keeps
it whole, unless ``N`` or more of the check's own cells (``_refN``, default 8; ``_hid``: of the random hidden cells only, not the outer ones; ``_n3``: the threshold at least three
times the full scan's own noise, ``SHADOW_MARGIN * scan_noise``) carry such a
correction in the thinned map: the scan can then measure it, and those cells' least-squares
weight (``selfcheck.correction_weight``) holds instead. Only unobserved cells of each map
change. The rest of the check as shipped (shadows, reach, keep-far, membrane).

usage: THREADS=2 python tools/probes/dig_keep.py --fills-cache outputs/fills_cache.json \
           DIG10_check_reach_keepfar_sigma_membrane_dig10=shipped
"""

import re

import torch
from common import run

import warp_terrain.inference.reconstructor as reconstructor
import warp_terrain.inference.selfcheck as check
from warp_terrain.inference.shadows import shadow_cells

PROBE: dict = {}


def is_large(correction: torch.Tensor, margin=None) -> torch.Tensor:
    tau = PROBE["tau"]
    if PROBE["noise"] and margin is not None:  # and beyond three times the scan's own noise
        tau = torch.clamp(margin, min=tau)
    return correction < -tau if PROBE["sign"] < 0 else correction.abs() > tau


def checked_maps(fills, model, scan, mask, thinned, regimes, membrane, keep_far, shadow_margin=None, large=None):
    """``selfcheck.checked_maps``, large corrections kept whole unless the check's cells refute them
    (the probe's rule in place of the file's own ``large``)."""
    if "tau" not in PROBE:
        return check.checked_maps(fills, model, scan, mask, thinned, regimes, membrane, keep_far, shadow_margin, large)
    n = scan.shape[0]
    fill, fill_thinned = check.checked_fills(fills, scan, mask, thinned, regimes, membrane)
    w = regimes.weight(model[n:], fill_thinned, scan)
    if keep_far and w[1] is not None:
        w = (w[0], torch.ones_like(w[1]))
    fills2, observed2 = (fill, fill_thinned), (mask, thinned)
    if shadow_margin is not None:
        shadows = shadow_cells(torch.cat([scan, scan * thinned]), torch.cat([mask, thinned]), torch.cat([fill, fill_thinned]),
                               shadow_margin).split(n)
        keep = check.shadow_weight(model[n:], fill_thinned, scan, shadows[1] & regimes.checked)
    margins = (None, None) if shadow_margin is None else shadow_margin.split(n)
    cells = is_large(model[n:] - fill_thinned, margins[0]) & (regimes.hidden if PROBE["hidden_only"] else regimes.checked)
    refuted = cells.sum(dim=(2, 3), keepdim=True) >= PROBE["refute"]
    dig_keep = torch.where(refuted, check.correction_weight(model[n:], fill_thinned, scan, cells), torch.ones_like(refuted, dtype=fill.dtype))
    PROBE.setdefault("refuted", []).extend(zip(cells.sum(dim=(2, 3)).flatten().tolist(), dig_keep.flatten().tolist()))
    maps = []
    for i, (f, m, observed) in enumerate(zip(fills2, model.split(n), observed2)):
        weight = regimes.at(w, observed)
        if shadow_margin is not None:
            weight = torch.where(shadows[i], torch.maximum(weight, keep), weight)
        digs = is_large(m - f, margins[0]) & (observed <= 0)
        weight = torch.where(digs, torch.maximum(weight, dig_keep), weight)
        maps.append(f + weight * (m - f))
    return maps[0], maps[1]


def settings_of(name: str) -> dict:
    if m := re.search(r"_(dig|big)(\d+)", name):
        r = re.search(r"_ref(\d+)", name)
        return {"tau": int(m[2]) / 100.0, "sign": -1 if m[1] == "dig" else 0, "refute": int(r[1]) if r else 8,
                "hidden_only": "_hid" in name, "noise": "_n3" in name}
    return {}


if __name__ == "__main__":
    reconstructor.checked_maps = checked_maps
    try:
        run(settings_of, PROBE)
    finally:
        kept = [k for _, k in PROBE.get("refuted", [])]
        if kept:
            print(f"maps {len(kept)}: kept whole {sum(k == 1.0 for k in kept)}, "
                  f"median check cells {sorted(c for c, _ in PROBE['refuted'])[len(kept) // 2]}")
