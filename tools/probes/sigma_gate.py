"""Probe (docs/transfer.md, stop 41): trust the net's correction where the net itself is sure.

The self-check weighs the net's correction by what its hidden cells show; those cells are observed
open ground, where the fill is already right, while an obstacle's back or a pit, where the
correction pays, lies 2-7 cells from the scan and is never among them (stop 32). The net's
uncertainty head says, per cell, how far it expects to be off. Here a cell keeps at least

    g = clamp((|model - fill| / sigma - Z0) / (Z1 - Z0), 0, 1)

of the correction, ``sigma`` the net's own (before the check scales it): a correction many of its
own sigmas large is kept whatever the hidden cells say; a small one is weighed as shipped. The
thinned scan's map is gated the same way, so the check's sigma factors see the gated map.
NAME token ``_zA_B``: Z0 = A / 10, Z1 = B / 10 (no token: the shipped check).

usage: THREADS=2 python tools/probes/sigma_gate.py --fills-cache outputs/fills_cache.json \
           G_check_reach_keepfar_sigma_membrane_z20_40=shipped
"""

import re

import torch
from common import run

import warp_terrain.inference.reconstructor as reconstructor
import warp_terrain.inference.selfcheck as check

PROBE: dict = {}
plain_predict = reconstructor.Reconstructor._predict


def predict(self, scan, mask, tensions=(), noise=None):
    """``Reconstructor._predict``, remembering the net's sigma of the check's pass."""
    height, sigma, fills = plain_predict(self, scan, mask, tensions, noise)
    if tensions:
        PROBE["sigma"] = sigma
    return height, sigma, fills


def gate(model, fill, sigma):
    z = (model - fill).abs() / sigma.clamp_min(1e-6)
    return ((z - PROBE["z0"]) / (PROBE["z1"] - PROBE["z0"])).clamp(0.0, 1.0)


def checked_maps(fills, model, scan, mask, thinned, regimes, membrane, keep_far):
    """``selfcheck.checked_maps``, each cell keeping at least its gate's share of the correction."""
    if "z0" not in PROBE:
        return check.checked_maps(fills, model, scan, mask, thinned, regimes, membrane, keep_far)
    n, sigma = scan.shape[0], PROBE["sigma"]
    fill, fill_thinned = check.checked_fills(fills, scan, mask, thinned, regimes, membrane)
    w = regimes.weight(model[n:], fill_thinned, scan)
    if keep_far and w[1] is not None:
        w = (w[0], torch.ones_like(w[1]))
    out = []
    for f, m, s, observed in ((fill, model[:n], sigma[:n], mask), (fill_thinned, model[n:], sigma[n:], thinned)):
        weight = torch.maximum(regimes.at(w, observed), gate(m, f, s))
        out.append(f + weight * (m - f))
    return tuple(out)


def settings_of(name: str) -> dict:
    if m := re.search(r"_z(\d+)_(\d+)", name):
        return {"z0": int(m[1]) / 10.0, "z1": int(m[2]) / 10.0}
    return {}


if __name__ == "__main__":
    reconstructor.Reconstructor._predict = predict
    reconstructor.checked_maps = checked_maps
    run(settings_of, PROBE)
