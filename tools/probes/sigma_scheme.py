"""How the checked sigma's per-map factor could be laid over the map: the share of scored cells
within 1 sigma on every family of the real suite and the synthetic settings, under each scheme.

Phase one (``collect``) runs the shipped file's check once per family (orientation average on,
as shipped) and keeps what the check measured (the thinned map, its raw sigma, the hidden and
outer cells, the scan's noise) beside the full map, its raw sigma and the scored cells; phase
two (``schemes``, the default) lays the per-map factors over the map in several ways and prints
the shares, without running the model again.

usage: THREADS=2 python tools/probes/sigma_scheme.py collect [--size 32]   (writes outputs/sigma_scheme.pt)
       python tools/probes/sigma_scheme.py [schemes]
"""

import argparse
import os

import numpy as np
import torch
from common import load_checked
from scipy import ndimage

from warp_terrain.evaluation.real import DEM_FAMILIES, MAP, REAL_SEED_BASE, SCAN_FAMILIES, dem_family_set, real_data_dir, scan_family_set
from warp_terrain.evaluation.robustness import synthetic_edge_sets
from warp_terrain.evaluation.testsets import make_eval_set
from warp_terrain.inference.selfcheck import SHADOW_MARGIN, Regimes, check_cells, checked_maps, resolved_sigma_factor, scan_noise

CACHE = "outputs/sigma_scheme.pt"


def families(size: int):
    """``(name, scan, mask, truth, scored)`` of every family: DEMs and synthetic sets score the
    unobserved cells against the true map, scans the hidden cells against the measured heights."""
    folder = real_data_dir()
    for family in DEM_FAMILIES:
        ts = dem_family_set(family, folder, size, "cpu")
        yield family.name, ts.scan, ts.mask, ts.target, ts.mask <= 0
    for family in SCAN_FAMILIES:
        ss = scan_family_set(family, folder, 3, MAP.size, MAP.cell, REAL_SEED_BASE + 100 + SCAN_FAMILIES.index(family))
        yield family.name, ss.scan, ss.mask, ss.measured, ss.hidden
    for ts in synthetic_edge_sets(size, "cpu"):
        yield ts.terrain, ts.scan, ts.mask, ts.target, ts.mask <= 0
    for setting in ("octave5", "octave3", "flat_cylinders", "negative_obstacles"):
        for noise in (0.0, 0.1):
            ts = make_eval_set(setting, noise, size=size, device="cpu")
            yield f"{setting}/{noise}", ts.scan, ts.mask, ts.target, ts.mask <= 0


def check_parts(rec, scan, mask) -> dict:
    """What ``Reconstructor.check_maps`` computes, kept: maps and raw sigmas of the full and the thinned scans."""
    hidden, outer, thinned = check_cells(mask, True)
    n = scan.shape[0]
    both_scans, both_masks = torch.cat([scan, scan * thinned]), torch.cat([mask, thinned])
    noise = scan_noise(both_scans, both_masks)
    heights, sigmas, fills = rec._predict(both_scans, both_masks, rec.check_tensions, noise=noise)
    regimes = Regimes(hidden, outer, masks=(mask, thinned))
    height, height_thinned = checked_maps(fills, heights, scan, mask, thinned, regimes, rec.check_membrane, rec.check_keep_far,
                                          SHADOW_MARGIN * noise if rec.check_keep_shadows else None)
    return {"height": height, "sigma": sigmas[:n], "height_thinned": height_thinned, "sigma_thinned": sigmas[n:],
            "hidden": hidden, "outer": outer, "thinned": thinned, "noise": noise[:n]}


def collect(size: int) -> None:
    rec = load_checked("shipped")
    rec.check_keep_shadows = bool(rec.meta.get("check_keep_shadows", False))
    out = {}
    with torch.inference_mode():
        for name, scan, mask, truth, scored in families(size):
            parts = [check_parts(rec, scan[i:i + 16], mask[i:i + 16]) for i in range(0, scan.shape[0], 16)]
            entry = {k: torch.cat([p[k] for p in parts]) for k in parts[0]}
            entry.update(scan=scan, mask=mask, truth=truth, scored=scored)
            out[name] = entry
            print(name, flush=True)
    out["_meta"] = {"unresolved": rec.unresolved_sigma_factor}
    torch.save(out, CACHE)


def distance(mask: torch.Tensor) -> torch.Tensor:
    """(B, 1, S, S) Euclidean distance (cells) of each cell to the nearest cell of ``mask``."""
    return torch.from_numpy(np.stack([ndimage.distance_transform_edt(m[0].numpy() <= 0) for m in mask])[:, None]).float()


BINS = ((0.5, 1.5), (1.5, 2.5), (2.5, 4.5), (4.5, 8.5), (8.5, 1e9))


def regime_factors(e: dict, fallback: float, near_cells=None, away_cells=None):
    measure = lambda cells: resolved_sigma_factor(e["height_thinned"], e["sigma_thinned"], e["scan"], cells, noise=e["noise"])  # noqa: E731
    factors = []
    for cells in (e["hidden"] if near_cells is None else near_cells, e["outer"] if away_cells is None else away_cells):
        k, resolved = measure(cells)
        factors.append(torch.where(resolved.view(-1, 1, 1, 1), k, torch.full_like(k, fallback)))
    return factors


def shipped_factor(e: dict, fallback: float, combine=None, **cells) -> torch.Tensor:
    near, away = regime_factors(e, fallback, **cells)
    if combine is not None:
        away = combine(near, away)
    return Regimes(e["hidden"], e["outer"]).at((near, away), e["mask"])


def binned_factor(e: dict, fallback: float, edges=BINS, pool: bool = False) -> torch.Tensor:
    """Each checked cell (hidden or outer) binned by its distance to the thinned scan's nearest
    kept cell; a factor per bin where the bin resolves; each cell of the map takes the factor of
    its own distance to the full scan's nearest observed cell (the nearest resolved bin below,
    else above; else the fallback)."""
    checked = e["hidden"] | e["outer"]
    d_check, d_map = distance(e["thinned"]), distance(e["mask"])
    ks, oks = [], []
    for lo, hi in edges:
        cells = checked & (d_check > lo) & (d_check <= hi)
        k, resolved = resolved_sigma_factor(e["height_thinned"], e["sigma_thinned"], e["scan"], cells, noise=e["noise"])
        ks.append(k.view(-1))
        oks.append(resolved)
    ks, oks = torch.stack(ks, 1), torch.stack(oks, 1)  # (B, bins)
    if pool:  # a bin that does not resolve takes the largest resolved factor at a smaller distance
        for j in range(1, len(edges)):
            prev = torch.where(oks[:, :j], ks[:, :j], torch.zeros_like(ks[:, :j])).max(dim=1).values
            ks[:, j] = torch.where(oks[:, j], torch.maximum(ks[:, j], prev), ks[:, j])
    filled = ks.clone()
    for b in range(ks.shape[0]):
        good = [j for j in range(len(edges)) if oks[b, j]]
        for j in range(len(edges)):
            if not good:
                filled[b, j] = fallback
            elif not oks[b, j]:
                below = [g for g in good if g < j]
                filled[b, j] = ks[b, below[-1] if below else good[0]]
    factor = torch.zeros_like(d_map)
    for j, (lo, hi) in enumerate(edges):
        inside = (d_map > lo) & (d_map <= hi)
        factor = torch.where(inside, filled[:, j].view(-1, 1, 1, 1), factor)
    return torch.where(d_map <= 0.5, filled[:, 0].view(-1, 1, 1, 1), factor)


def schemes() -> None:
    data = torch.load(CACHE, weights_only=False)
    fallback = data.pop("_meta")["unresolved"]
    table = {"shipped": lambda e: shipped_factor(e, fallback),
             "per distance bin": lambda e: binned_factor(e, fallback),
             "near only": lambda e: shipped_factor(e, fallback, combine=lambda n, a: n),
             "min(near, away)": lambda e: shipped_factor(e, fallback, combine=torch.minimum),
             "geo mean": lambda e: shipped_factor(e, fallback, combine=lambda n, a: (n * a).sqrt()),
             "away d>=2": lambda e: shipped_factor(e, fallback, away_cells=e["outer"] & (distance(e["thinned"]) > 1.5)),
             "away d>=3": lambda e: shipped_factor(e, fallback, away_cells=e["outer"] & (distance(e["thinned"]) > 2.5))}
    print("| family | " + " | ".join(table) + " | shipped by distance (1, 2, 3-4, 5-8, 9+: share, within) |")
    print("|---|" + "---:|" * (len(table) + 1))
    for name, e in data.items():
        error = (e["height"] - e["truth"]).abs()
        cells = []
        for scheme, f in table.items():
            k = f(e)
            within = (error <= e["sigma"] * k)[e["scored"]].float().mean()
            cells.append(f"{100 * float(within):.0f} %")
            if scheme == "shipped":
                d = distance(e["mask"])
                inside = (error <= e["sigma"] * k)
                parts = []
                for lo, hi in BINS:
                    c = e["scored"] & (d > lo) & (d <= hi)
                    parts.append(f"{float(c.sum() / e['scored'].sum()):.0%} {float(inside[c].float().mean()) if c.any() else float('nan'):.0%}")
                by_distance = ", ".join(parts)
        print(f"| {name} | " + " | ".join(cells) + f" | {by_distance} |", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("phase", nargs="?", default="schemes", choices=("collect", "schemes"))
    parser.add_argument("--size", type=int, default=32)
    args = parser.parse_args()
    torch.set_num_threads(int(os.environ.get("THREADS", "2")))
    collect(args.size) if args.phase == "collect" else schemes()


if __name__ == "__main__":
    main()
