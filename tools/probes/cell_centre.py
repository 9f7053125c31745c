"""A cell's height moved to its centre: the mean of its returns lies where its returns lie, not
at the cell's centre, and on a slope it is off by slope x offset, an error that neighbouring
cells along a ring share (the check cannot tell it from the ground's). This probe corrects each
observed cell by the thin plate's gradient there times its returns' mean offset from the centre
(the gradient clamped to ``--gmax``, the thin plate refitted on the corrected heights
``--iters`` times) and prints, per set, the observed cells' RMSE, two classical fills' RMSE on
unobserved cells, and the shipped checked model's RMSE and share within 1 sigma, from the mean
heights and from the corrected ones (no orientation average).

usage: python tools/probes/cell_centre.py [--size N] [--gmax G] [--iters K] [--no-model] [--tta]
"""

import argparse

import torch
import torch.nn.functional as F
from common import load_checked

from warp_terrain.evaluation.real import DEM_FAMILIES, REAL_SEED_BASE, _dem_sim, real_data_dir
from warp_terrain.evaluation.testsets import eval_seeds, setting_config
from warp_terrain.models.biharmonic import biharmonic_fill
from warp_terrain.sim.batch import generate_batch


def offsets(points: torch.Tensor, size: int, cell: float):
    """(B, 1, S, S) mean x and y offsets of each cell's points from its centre (0 where none)."""
    batch = points.shape[0]
    half = (size - 1) / 2
    ok = torch.isfinite(points).all(-1)
    p = torch.where(ok[..., None], points, torch.zeros_like(points))
    fi = torch.floor(p[..., 0] / cell + half + 0.5)  # float32, as the kernel bins them
    fj = torch.floor(p[..., 1] / cell + half + 0.5)
    ok &= (fi >= 0) & (fj >= 0) & (fi < size) & (fj < size)
    d = torch.stack([torch.ones_like(fi), p[..., 0] - (fi - half) * cell, p[..., 1] - (fj - half) * cell], -1).double()
    index = (torch.arange(batch)[:, None] * size * size + fi * size + fj).long()
    sums = torch.zeros(batch * size * size, 3, dtype=torch.float64).index_add_(0, index[ok], d[ok])
    sums = sums.view(batch, size, size, 3)
    n = sums[..., 0].clamp(min=1)
    return (sums[..., 1] / n).float()[:, None], (sums[..., 2] / n).float()[:, None]


def centred(scan, mask, dx, dy, cell, gmax, iters):
    h = scan * mask
    for _ in range(iters):
        f = biharmonic_fill(h, mask, tension=0.0)
        p = F.pad(f, (1, 1, 1, 1), mode="replicate")
        gx = (p[..., 2:, 1:-1] - p[..., :-2, 1:-1]) / (2 * cell)
        gy = (p[..., 1:-1, 2:] - p[..., 1:-1, :-2]) / (2 * cell)
        g = torch.sqrt(gx * gx + gy * gy)
        shrink = torch.where(g > gmax, gmax / g.clamp(min=1e-12), torch.ones_like(g))
        h = (scan - shrink * (gx * dx + gy * dy)) * mask
    return h


def sets(size):
    for terrain in ("octave3", "octave5", "flat_cylinders", "negative_obstacles"):
        sim = setting_config(terrain)
        yield terrain, sim, eval_seeds(size)
    folder = real_data_dir()
    for i, family in enumerate(DEM_FAMILIES):
        if not family.obstacles:
            yield family.name, _dem_sim(family, folder), [REAL_SEED_BASE + i]


def rmse(a, b, cells):
    return float(((a - b)[cells] ** 2).mean().sqrt())


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--size", type=int, default=32)
    parser.add_argument("--gmax", type=float, default=1.0)
    parser.add_argument("--iters", type=int, default=2)
    parser.add_argument("--no-model", action="store_true")
    parser.add_argument("--tta", action="store_true", help="the shipped 8-orientation average")
    args = parser.parse_args()
    rec = None if args.no_model else load_checked("shipped", tta=args.tta)
    print("| set | cell height | observed RMSE | thin plate | membrane | model | model within 1 sigma |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for name, sim, seeds in sets(args.size):
        chunk = args.size // len(seeds)
        parts = [generate_batch(chunk, sim, seed=s, device="cpu") for s in seeds]
        scan, mask, target = (torch.cat([getattr(b, k) for b in parts]) for k in ("scan", "mask", "target"))
        cell, size = sim.data.map_cell, sim.data.map_size
        dx, dy = (torch.cat(t) for t in zip(*(offsets(b.points, size, cell) for b in parts)))
        observed, unobserved = mask > 0, mask == 0
        for label, h in (("mean", scan * mask), ("centred", centred(scan, mask, dx, dy, cell, args.gmax, args.iters))):
            fills = [rmse(biharmonic_fill(h, mask, tension=t), target, unobserved) for t in (0.0, 1.0)]
            model = "-", "-"
            if rec is not None:
                outs = [rec.predict_maps_with_uncertainty(h[i:i + 16], mask[i:i + 16]) for i in range(0, h.shape[0], 16)]
                pred, sigma = torch.cat([o[0] for o in outs]), torch.cat([o[1] for o in outs])
                within = float(((pred - target).abs() <= sigma)[unobserved].float().mean())
                model = f"{rmse(pred, target, unobserved):.4f}", f"{within:.0%}"
            print(f"| {name} | {label} | {rmse(h, target, observed):.4f} | {fills[0]:.4f} | {fills[1]:.4f} | {model[0]} | {model[1]} |", flush=True)


if __name__ == "__main__":
    main()
