"""Per map, how often the checked sigma means what it says: for each set, the shipped model's
share of unobserved cells within 1 sigma over all maps and how many maps fall under 40 % or over
85 % on their own, with the check's sigma factor as shipped, as in stops 31-32 (no resolution
rule: a map whose checked errors sit under the scan's noise gets a factor of about 0), and at 1
everywhere (the file's own calibration, ``sigma_scale``).

usage: python tools/probes/sigma_per_map.py [--size N] [--tta]
"""

import argparse
from functools import partial

import torch
from common import load_checked

import warp_terrain.inference.reconstructor as reconstructor
from warp_terrain.evaluation.testsets import make_eval_set
from warp_terrain.inference.selfcheck import sigma_factor

SETS = (("negative_obstacles", 0.05), ("negative_obstacles", 0.1), ("octave3", 0.05), ("octave5", 0.1), ("flat_cylinders", 0.1),
        ("octave3", 0.0), ("flat_cylinders", 0.0))
FACTORS = {
    "shipped": sigma_factor,
    "stops 31-32": partial(sigma_factor, resolution=float("-inf")),
    "k = 1": lambda predicted, sigma, *args, **kwargs: torch.ones(sigma.shape[0], 1, 1, 1, dtype=sigma.dtype),
}


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--size", type=int, default=32)
    parser.add_argument("--tta", action="store_true")
    args = parser.parse_args()
    rec = load_checked("shipped", tta=args.tta)
    print("| set | " + " | ".join(f"{name}: within 1 sigma (maps < 40 % / > 85 %)" for name in FACTORS) + " |")
    print("|---|" + "---:|" * len(FACTORS))
    for terrain, noise in SETS:
        ts = make_eval_set(terrain, noise, size=args.size, device="cpu")
        unobserved = ts.mask == 0
        cells = []
        for factor in FACTORS.values():
            reconstructor.sigma_factor = factor
            parts = [rec.predict_maps_with_uncertainty(ts.scan[i:i + 16], ts.mask[i:i + 16]) for i in range(0, args.size, 16)]
            height, sigma = torch.cat([h for h, _ in parts]), torch.cat([s for _, s in parts])
            within = (height - ts.target).abs() <= sigma
            per_map = (within & unobserved).flatten(1).sum(1) / unobserved.flatten(1).sum(1)
            cells.append(f"{float(within[unobserved].float().mean()):.0%} ({int((per_map < 0.4).sum())} / {int((per_map > 0.85).sum())})")
        print(f"| {terrain}/noise{noise:g} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
