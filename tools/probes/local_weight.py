"""Probe (docs/transfer.md): the self-check's correction weight per neighbourhood
instead of per map. The check weighs the net's correction by one least-squares weight per map,
measured on the hidden cells; where the net is right in one part of a map (an obstacle's edge) and
wrong in another (open ground), one weight keeps neither. Here the weight at a cell is the least-
squares weight of the hidden cells in the (2R+1)^2 window about it, shrunk towards the map's own:

    w(x) = (sum_win d r + k w_map) / (sum_win d^2 + k),   k = L * sum_map d^2 * window / map area,

``d`` the correction and ``r`` the measured height less the fill on the hidden cells: ``L`` = 1
weighs a window of average correction as much as the map's weight. NAME tokens: ``_locR`` the
window's half width (cells), ``_lamL`` the shrinkage (default 1), ``_locbeta`` the membrane's share
per window too. ``_magT`` instead weighs the correction per size: one least-squares weight for the
hidden cells whose correction is under ``T`` cm, one for those at or over it (each shrunk towards
the map's weight as above, with the bin's share of cells in place of the window's): an obstacle's
or a pit's large correction is then judged on the cells where the net corrects by as much, not
swamped by the many small corrections of open ground. Without either token the check is the
shipped one.

usage: THREADS=1 python tools/probes/local_weight.py --fills-cache outputs/fills_cache.json \
           L8_check_reach_keepfar_sigma_membrane_loc8=shipped
"""

import re

import torch
from common import run

import warp_terrain.inference.reconstructor as reconstructor
import warp_terrain.inference.selfcheck as check

PROBE: dict = {}


def window_sum(x: torch.Tensor, radius: int) -> torch.Tensor:
    size = 2 * radius + 1
    return torch.nn.functional.avg_pool2d(x, size, stride=1, padding=radius, count_include_pad=True) * size * size


def local_weight(candidate, fill, measured, cells):
    """(B, 1, S, S) per-cell weight of ``candidate - fill`` (the module docstring)."""
    radius, shrink = PROBE["radius"], PROBE["shrink"]
    h = cells.to(candidate.dtype)
    d = (candidate - fill) * h
    r = (measured - fill) * h
    map_weight = check.correction_weight(candidate, fill, measured, cells)
    den_map = (d * d).sum(dim=(2, 3), keepdim=True)
    size = candidate.shape[-1]
    k = shrink * den_map * (2 * radius + 1) ** 2 / (size * size)
    num, den = window_sum(d * r, radius), window_sum(d * d, radius)
    w = (num + k * map_weight) / (den + k).clamp_min(1e-30)
    return torch.where(den_map > 0, w, torch.zeros_like(w)).clamp(0.0, 1.0)


def size_weights(candidate, fill, measured, cells):
    """``(large, small)``, each (B, 1, 1, 1): the weights of ``candidate - fill`` on the cells whose
    correction is at least / under the threshold (the module docstring)."""
    threshold, shrink = PROBE["magnitude"], PROBE["shrink"]
    correction = candidate - fill
    large = correction.abs() >= threshold
    map_weight = check.correction_weight(candidate, fill, measured, cells)
    h = cells.to(candidate.dtype)
    d, r = correction * h, (measured - fill) * h
    den_map = (d * d).sum(dim=(2, 3), keepdim=True)
    count = h.sum(dim=(2, 3), keepdim=True).clamp_min(1.0)
    out = []
    for part in (large, ~large):
        p = part.to(candidate.dtype)
        k = shrink * den_map * (h * p).sum(dim=(2, 3), keepdim=True) / count
        w = ((d * r * p).sum(dim=(2, 3), keepdim=True) + k * map_weight) / ((d * d * p).sum(dim=(2, 3), keepdim=True) + k).clamp_min(1e-30)
        out.append(torch.where(den_map > 0, w, torch.zeros_like(w)).clamp(0.0, 1.0))
    return out


def per_size(weights, candidate, fill):
    """(B, 1, S, S): each cell's weight by the size of its own correction."""
    large, small = weights
    return torch.where((candidate - fill).abs() >= PROBE["magnitude"], large, small)


def weight(regimes, candidate, fill, measured):
    near = local_weight(candidate, fill, measured, regimes.hidden)
    away = None if regimes.outer is None else check.correction_weight(candidate, fill, measured, regimes.outer)
    return near, away


def checked_maps(fills, model, scan, mask, thinned, regimes, membrane, keep_far):
    """``selfcheck.checked_maps`` with the net's weight (and with ``_locbeta`` the membrane's) per window."""
    if "radius" not in PROBE and "magnitude" not in PROBE:
        return check.checked_maps(fills, model, scan, mask, thinned, regimes, membrane, keep_far)
    n = scan.shape[0]
    smooth = fills[:-1] if membrane else fills
    choice = check.best_fill(smooth[:, n:], scan, regimes.hidden)
    fill, fill_thinned = check.pick(smooth[:, :n], choice), check.pick(smooth[:, n:], choice)
    if membrane:
        beta = (weight(regimes, fills[-1, n:], fill_thinned, scan) if PROBE["beta"]
                else regimes.weight(fills[-1, n:], fill_thinned, scan))
        fill = regimes.apply(beta, fill, fills[-1, :n], mask)
        fill_thinned = regimes.apply(beta, fill_thinned, fills[-1, n:], thinned)
    if "magnitude" in PROBE:
        sizes = size_weights(model[n:], fill_thinned, scan, regimes.hidden)
        away = regimes.weight(model[n:], fill_thinned, scan)[1]
        away = None if away is None else (torch.ones_like(away) if keep_far else away)
        w_full = (per_size(sizes, model[:n], fill), away)
        w_thin = (per_size(sizes, model[n:], fill_thinned), away)
        return regimes.apply(w_full, fill, model[:n], mask), regimes.apply(w_thin, fill_thinned, model[n:], thinned)
    w = weight(regimes, model[n:], fill_thinned, scan)
    if keep_far and w[1] is not None:
        w = (w[0], torch.ones_like(w[1]))
    return regimes.apply(w, fill, model[:n], mask), regimes.apply(w, fill_thinned, model[n:], thinned)


def settings_of(name: str) -> dict:
    out = {"beta": "_locbeta" in name, "shrink": 1.0}
    if m := re.search(r"_loc(\d+)", name):
        out["radius"] = int(m[1])
    if m := re.search(r"_mag(\d+)", name):
        out["magnitude"] = int(m[1]) / 100.0
    if m := re.search(r"_lam([\d.]+)", name):
        out["shrink"] = float(m[1].rstrip("."))
    return out


if __name__ == "__main__":
    reconstructor.checked_maps = checked_maps
    run(settings_of, PROBE)
