"""What a cell's height should be: the mean of its returns (the simulator's and the shipped
model's projection), their lowest, or their highest. A cell on a pit's far wall holds returns
from halfway up the wall while its centre lies on the floor; a cell on a cylinder's side holds
returns below the top. This probe projects the same simulated scans three ways and prints, per
setting, the observed cells' RMSE against the true height and two classical fills' RMSE on
unobserved cells (the thin plate and the membrane, ``models.biharmonic``), no network: whether
the projection rule is worth a channel for the net.

usage: python tools/probes/cell_height.py [--size N]
"""

import argparse

import torch
import warp as wp

from warp_terrain.evaluation.testsets import setting_config
from warp_terrain.models.biharmonic import biharmonic_fill
from warp_terrain.sim.batch import generate_batch
from warp_terrain.sim.projection import bin_into_maps

SETTINGS = ("negative_obstacles", "flat_cylinders", "octave3", "octave5")
SEED = 0x51D0


def lowest(points: torch.Tensor, size: int, cell: float) -> torch.Tensor:
    """(B, 1, S, S) lowest z of each cell's points: the highest of the points with z negated."""
    flipped = points.clone()
    flipped[..., 2] = -flipped[..., 2]
    _, top, _ = bin_into_maps(wp.from_torch(flipped.contiguous(), dtype=wp.vec3), size, cell, "cpu")
    return -wp.to_torch(top)


def rmse(a: torch.Tensor, b: torch.Tensor, cells: torch.Tensor) -> float:
    return float(((a - b)[cells] ** 2).mean().sqrt())


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--size", type=int, default=32)
    args = parser.parse_args()
    print("| setting | cell height | observed cells' RMSE (m) | thin plate, unobserved (m) | membrane, unobserved (m) |")
    print("|---|---|---:|---:|---:|")
    for terrain in SETTINGS:
        sim = setting_config(terrain)
        b = generate_batch(args.size, sim, seed=SEED, device="cpu")
        mask, target = b.mask, b.target
        observed, unobserved = mask > 0, mask == 0
        low = lowest(b.points, sim.data.map_size, sim.data.map_cell) * mask
        for name, scan in (("mean", b.scan), ("lowest", low), ("highest", b.scan_max * mask)):
            fills = [biharmonic_fill(scan, mask, tension=t) for t in (0.0, 1.0)]
            print(f"| {terrain} | {name} | {rmse(scan, target, observed):.4f} | {rmse(fills[0], target, unobserved):.4f} | "
                  f"{rmse(fills[1], target, unobserved):.4f} |", flush=True)


if __name__ == "__main__":
    main()
