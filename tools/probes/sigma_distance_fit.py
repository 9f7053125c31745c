"""A sigma recalibrated by distance from the scan: one factor per distance bin (cells to the
nearest observed cell), fitted after the check on validation pairs of the shipped recipe's own
world (``experiment=pretrained_cycle1``'s randomised world, the validation seeds: never trained on),
so that 68 % of each bin's unobserved cells lie within 1 sigma; then applied to the sets of
``sigma_by_distance.py``, which the fit never sees. Prints the factors and, per set, the share
within 1 sigma of the shipped check and of the recalibrated one, overall and per bin.
No orientation average.

usage: python tools/probes/sigma_distance_fit.py [--fit-size N] [--centred]
"""

import argparse

import numpy as np
import torch
from cell_centre import sets
from common import load_checked
from scipy import ndimage
from sigma_by_distance import BINS

from warp_terrain.compose import compose_run
from warp_terrain.data.seeds import validation_seed
from warp_terrain.models.centring import centre_cells
from warp_terrain.sim import as_sim_config
from warp_terrain.sim.batch import generate_batch
from warp_terrain.sim.projection import cell_offsets


def distances(mask: torch.Tensor) -> torch.Tensor:
    return torch.from_numpy(np.stack([ndimage.distance_transform_edt(m[0].numpy() == 0) for m in mask]))[:, None].float()


def bin_index(distance: torch.Tensor) -> torch.Tensor:
    index = torch.full_like(distance, -1, dtype=torch.long)
    for k, (a, b) in enumerate(BINS):
        index[(distance >= a - 0.5) & (distance < (b if b else 1e9) + 0.5)] = k
    return index


def predicted(rec, batches, centred: bool):
    """(error, sigma, bin) of every map's cells, the maps predicted in chunks of 16."""
    errors, sigmas, bins, masks = [], [], [], []
    for b, cell in batches:
        scan = b.scan * b.mask
        if centred:
            scan = centre_cells(scan, b.mask, cell_offsets(b.points, b.mask.shape[-1], cell, device="cpu"), cell)
        for i in range(0, scan.shape[0], 16):
            h, s = rec.predict_maps_with_uncertainty(scan[i:i + 16], b.mask[i:i + 16])
            errors.append((h - b.target[i:i + 16]).abs())
            sigmas.append(s)
        bins.append(bin_index(distances(b.mask)))
        masks.append(b.mask)
    return torch.cat(errors), torch.cat(sigmas), torch.cat(bins), torch.cat(masks)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--fit-size", type=int, default=128)
    parser.add_argument("--centred", action="store_true", help="the model given centred cells (models.centring)")
    args = parser.parse_args()
    rec = load_checked("shipped", tta=False)
    sim = as_sim_config(compose_run(["experiment=pretrained_cycle1"]))
    fit = [(generate_batch(16, sim, seed=validation_seed(100 + i), device="cpu"), sim.data.map_cell) for i in range(args.fit_size // 16)]
    error, sigma, bins, mask = predicted(rec, fit, args.centred)
    ratio = error / sigma.clamp_min(1e-6)
    factors = []
    for k in range(len(BINS)):
        chosen = (mask == 0) & (bins == k)
        factors.append(float(torch.quantile(ratio[chosen].flatten()[:1_000_000], 0.68)) if bool(chosen.any()) else 1.0)
    print("factors per bin (fitted on the recipe's world):", ", ".join(f"{f:.2f}" for f in factors))
    table = torch.tensor(factors)
    print("| set | within 1 sigma: checked | recalibrated | " + " | ".join(f"bin {a}-{b or ''}" for a, b in BINS) + " |")
    for name, sim_set, seeds in sets(32, False):
        chunk = 32 // len(seeds)
        batches = [(generate_batch(chunk, sim_set, seed=s, device="cpu"), sim_set.data.map_cell) for s in seeds]
        error, sigma, bins, mask = predicted(rec, batches, args.centred)
        unobserved = mask == 0
        scaled = sigma * table[bins.clamp_min(0)]
        before = (error <= sigma)[unobserved].float().mean()
        after = (error <= scaled)[unobserved].float().mean()
        per_bin = [f"{float((error <= scaled)[unobserved & (bins == k)].float().mean()):.0%}" if bool((unobserved & (bins == k)).any())
                   else "-" for k in range(len(BINS))]
        print(f"| {name} | {float(before):.0%} | {float(after):.0%} | " + " | ".join(per_bin) + " |", flush=True)


if __name__ == "__main__":
    main()
