"""Probe (docs/transfer.md, stop 41): keep the net's correction whole in the scan's shadows.

The check's hidden cells were all seen by the sensor; a cell behind an obstacle was not, and
there (an obstacle's back, 2-7 cells from the scan) the check's near weight governs a correction
it never measured (stop 32). The scan says which unobserved cells lie in a shadow: along the ray
from the sensor (the map's centre, height 0) to a cell at distance ``r``, every observed cell
``k`` in front of it bounds the line of sight from below, and a surface at ``r`` lower than

    horizon(r) = r * max_k (z_k - M * noise) / r_k

cannot have been seen (``noise``: the scan's own, ``selfcheck.scan_noise``; ``M`` its margin).
A cell is in shadow where the check's classical fill lies below that horizon by more than
``D`` cm: the fill, not the net, decides it. There the correction is kept whole (as far from
the scan with ``check_keep_far``); elsewhere the check weighs it as shipped. The thinned scan's
map is kept the same way (its own horizon), so the check's sigma factors see the kept map.
The horizon is the package's (``inference/shadows.py``; the stop-41 figures of this probe were
measured with its first rays, sampled every half cell, before they moved there as digital lines;
the production row ``SD1`` reproduced ``_sh3_0_shv4`` to the second decimal). NAME tokens ``_shM_D``: margin ``M`` noises, ``D`` cm below the horizon (no token: shipped);
``_shvN``: where N or more of the check's hidden cells (all seen by the sensor) lie in the thinned
scan's shadows, the horizon is refuted there (overhangs, thin clutter): the shadows then keep the
correction's least-squares weight on those cells instead of all of it.

usage: THREADS=2 python tools/probes/shadow_keep.py --fills-cache outputs/fills_cache.json \
           SH_check_reach_keepfar_sigma_membrane_sh3_0=shipped
"""

import re

import torch
from common import run

import warp_terrain.inference.reconstructor as reconstructor
import warp_terrain.inference.selfcheck as check
from warp_terrain.inference.shadows import shadow_cells
from warp_terrain.models.noise import scan_noise

PROBE: dict = {}


def shadow(scan, mask, fill):
    """(B, 1, S, S) bool: unobserved cells whose fill lies ``D`` below the horizon (module docstring)."""
    return shadow_cells(scan, mask, fill + PROBE["depth"], PROBE["margin"] * scan_noise(scan, mask))


def checked_maps(fills, model, scan, mask, thinned, regimes, membrane, keep_far):
    """``selfcheck.checked_maps``, the correction kept whole in the scan's shadows."""
    if "margin" not in PROBE:
        return check.checked_maps(fills, model, scan, mask, thinned, regimes, membrane, keep_far)
    n = scan.shape[0]
    fill, fill_thinned = check.checked_fills(fills, scan, mask, thinned, regimes, membrane)
    w = regimes.weight(model[n:], fill_thinned, scan)
    if keep_far and w[1] is not None:
        w = (w[0], torch.ones_like(w[1]))
    keep = torch.ones_like(fill[:, :, :1, :1])
    if PROBE["verify"]:  # the check's cells the thinned map puts in shadow were seen: weigh the net there
        cells = shadow(scan * thinned, thinned, fill_thinned) & (regimes.hidden | (regimes.outer if regimes.outer is not None else False))
        measured = check.correction_weight(model[n:], fill_thinned, scan, cells)
        enough = cells.sum(dim=(2, 3), keepdim=True) >= PROBE["verify"]
        keep = torch.where(enough, measured, keep)
        PROBE.setdefault("verified", []).extend(zip(cells.sum(dim=(2, 3)).flatten().tolist(), keep.flatten().tolist()))
    out = []
    for f, m, s, observed in ((fill, model[:n], scan, mask), (fill_thinned, model[n:], scan * thinned, thinned)):
        weight = torch.where(shadow(s, observed, f), torch.maximum(keep, regimes.at(w, observed)), regimes.at(w, observed))
        out.append(f + weight * (m - f))
    PROBE.setdefault("shares", []).append(shadow(scan, mask, fill).float().mean().item())
    return tuple(out)


def settings_of(name: str) -> dict:
    if m := re.search(r"_sh(\d+)_(\d+)", name):
        v = re.search(r"_shv(\d+)", name)
        return {"margin": float(m[1]), "depth": int(m[2]) / 100.0, "verify": int(v[1]) if v else 0}
    return {}


if __name__ == "__main__":
    reconstructor.checked_maps = checked_maps
    run(settings_of, PROBE)
