"""Probe (docs/transfer.md): other far weights for the self-check's correction.
NAME tokens: ``_rN_M`` the correction's near/far ramp (``far_share(near=N, far=M)``, default 2_8);
``_wfar1`` the far weight 1 (what ``check_keep_far`` does); ``_veto`` 1 unless the outer cells'
weight is below 1/2; ``_odK`` the far weight measured only on the outer cells K or more cells
from a kept one (the plain weight where fewer than 16 are).

usage: python tools/probes/far_weight.py --fills-cache outputs/fills_cache.json C_check_notta_nokeepfar_veto=shipped ...
"""

import re

import torch
from common import run

import warp_terrain.inference.reconstructor as reconstructor
import warp_terrain.inference.selfcheck as check

PROBE: dict = {}


def blend(values, observed, near, far):
    near_w, away = values
    if away is None:
        return near_w
    share = check.far_share(observed, near, far).to(near_w.dtype)
    return near_w * (1 - share) + away * share


def far_weight(w, model, fill_thinned, scan, thinned, regimes):
    near_w, away = w
    if away is None:
        return w
    if "od" in PROBE:
        distance = check.far_share(thinned, 0, 8) * 8
        cells = regimes.outer & (distance >= PROBE["od"] - 0.5)
        enough = (cells.flatten(1).sum(1) >= 16).view(-1, 1, 1, 1)
        away = torch.where(enough, check.correction_weight(model, fill_thinned, scan, cells), away)
    if PROBE.get("veto"):
        away = torch.where(away >= 0.5, torch.ones_like(away), away)
    if PROBE.get("wfar1"):
        away = torch.ones_like(away)
    return near_w, away


def checked_maps(fills, model, scan, mask, thinned, regimes, membrane, keep_far=False):
    """``selfcheck.checked_maps`` with the probe's ramp and far weight (``keep_far`` ignored)."""
    n = scan.shape[0]
    near, far = PROBE.get("ramp", (check.REACH_NEAR, check.REACH_FAR))
    smooth = fills[:-1] if membrane else fills
    choice = check.best_fill(smooth[:, n:], scan, regimes.hidden)
    fill, fill_thinned = check.pick(smooth[:, :n], choice), check.pick(smooth[:, n:], choice)
    if membrane:
        beta = regimes.weight(fills[-1, n:], fill_thinned, scan)
        fill = regimes.apply(beta, fill, fills[-1, :n], mask)
        fill_thinned = regimes.apply(beta, fill_thinned, fills[-1, n:], thinned)
    w = far_weight(regimes.weight(model[n:], fill_thinned, scan), model[n:], fill_thinned, scan, thinned, regimes)
    return (fill + blend(w, mask, near, far) * (model[:n] - fill),
            fill_thinned + blend(w, thinned, near, far) * (model[n:] - fill_thinned))


def settings_of(name: str) -> dict:
    out = {"wfar1": "_wfar1" in name, "veto": "_veto" in name}
    if m := re.search(r"_r(\d+)_(\d+)", name):
        out["ramp"] = (int(m[1]), int(m[2]))
    if m := re.search(r"_od(\d+)", name):
        out["od"] = int(m[1])
    return out


if __name__ == "__main__":
    reconstructor.checked_maps = checked_maps
    run(settings_of, PROBE)
