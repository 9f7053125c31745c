"""A cell's height moved to its centre (``models.centring.centre_cells``): the mean of its
returns lies where its returns lie, not at the cell's centre, and on a slope it is off by slope x
offset, an error that neighbouring cells along a ring share (the check cannot tell it from the
ground's). This probe corrects each observed cell by the thin plate's gradient there times its
returns' mean offset from the centre (``sim.projection.cell_offsets``; the gradient clamped to
``--gmax``, averaged over ``--span`` metres, the thin plate solved ``--iters`` times, each on
the last corrected heights) and prints, per set, the observed cells' RMSE, two classical fills'
RMSE on unobserved cells, and the checked model's RMSE and share within 1 sigma (the shipped
file, or ``--model``, checked as the shipped file is), from the mean heights and from the
corrected ones (the 8-orientation average with ``--tta``). 32 maps per set: the evaluation's
seeds for the synthetic settings, the real suite's for its DEM families without obstacles.
``--scans``: the real suite's real scans instead (``real_scans``).

usage: python tools/probes/cell_centre.py [--size N] [--gmax G] [--iters K] [--span M] [--no-model | --model PATH] [--tta] [--noisy | --scans]
"""

import argparse

import torch
from common import load_checked

from warp_terrain.data.scans import load_scan
from warp_terrain.evaluation.real import DEM_FAMILIES, REAL_SEED_BASE, SCAN_FAMILIES, _dem_sim, real_data_dir, scan_family_set
from warp_terrain.evaluation.testsets import eval_seeds, setting_config
from warp_terrain.models.biharmonic import biharmonic_fill
from warp_terrain.models.centring import GRADIENT_SPAN, MAX_SLOPE, centre_cells
from warp_terrain.sim.batch import generate_batch
from warp_terrain.sim.projection import cell_offsets


def sets(size, noisy: bool):
    for terrain in ("octave3", "octave5", "flat_cylinders", "negative_obstacles"):
        for noise in (0.0, 0.05, 0.1) if noisy else (0.0,):
            yield (f"{terrain}/noise{noise}" if noisy else terrain), setting_config(terrain, noise), eval_seeds(size)
    if noisy:
        return
    folder = real_data_dir()
    for i, family in enumerate(DEM_FAMILIES):
        if not family.obstacles:
            yield family.name, _dem_sim(family, folder), [REAL_SEED_BASE + i]


def rmse(a, b, cells):
    return float(((a - b)[cells] ** 2).mean().sqrt())


def real_scans(rec, args) -> None:
    """The real suite's scan families (20 % of each scan's observed cells hidden, 3 draws, the
    suite's seeds): the model from mean and from centred heights, each scored on the hidden
    cells against their measured mean heights (the suite's score) and against the full scan's
    centred heights."""
    folder = real_data_dir()
    print("| family | input | against mean heights | against centred heights | within 1 sigma (mean heights) |")
    print("|---|---|---:|---:|---:|")
    for i, family in enumerate(SCAN_FAMILIES):
        repeats = 3
        ss = scan_family_set(family, folder, repeats, 121, 0.25, REAL_SEED_BASE + 100 + i)
        offsets = torch.cat([cell_offsets(load_scan(folder / name), 121, 0.25, device="cpu") for name in family.files
                             for _ in range(repeats)])
        full = (ss.mask > 0) | ss.hidden
        centred_truth = centre_cells(ss.measured, full.float(), offsets, 0.25, span=args.span)
        for label, h in (("mean", ss.scan), ("centred", centre_cells(ss.scan, ss.mask, offsets, 0.25, span=args.span))):
            outs = [rec.predict_maps_with_uncertainty(h[j:j + 16], ss.mask[j:j + 16]) for j in range(0, h.shape[0], 16)]
            pred, sigma = torch.cat([o[0] for o in outs]), torch.cat([o[1] for o in outs])
            within = float(((pred - ss.measured).abs() <= sigma)[ss.hidden].float().mean())
            print(f"| {family.name} | {label} | {rmse(pred, ss.measured, ss.hidden):.4f} | {rmse(pred, centred_truth, ss.hidden):.4f} | "
                  f"{within:.0%} |", flush=True)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--size", type=int, default=32)
    parser.add_argument("--gmax", type=float, default=MAX_SLOPE)
    parser.add_argument("--iters", type=int, default=1)
    parser.add_argument("--span", type=float, default=GRADIENT_SPAN, help="metres over which the gradient is averaged (0: none)")
    parser.add_argument("--no-model", action="store_true")
    parser.add_argument("--tta", action="store_true", help="the shipped 8-orientation average")
    parser.add_argument("--noisy", action="store_true", help="the synthetic settings with 0, 5 and 10 %% image noise instead")
    parser.add_argument("--scans", action="store_true", help="the real suite's real scans instead")
    parser.add_argument("--model", default="shipped", help="a Reconstructor file or checkpoint, checked as the shipped file is")
    args = parser.parse_args()
    rec = None if args.no_model else load_checked(args.model, tta=args.tta)
    if args.scans:
        return real_scans(rec, args)
    print("| set | cell height | observed RMSE | thin plate | membrane | model | model within 1 sigma |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for name, sim, seeds in sets(args.size, args.noisy):
        chunk = args.size // len(seeds)
        parts = [generate_batch(chunk, sim, seed=s, device="cpu") for s in seeds]
        scan, mask, target = (torch.cat([getattr(b, k) for b in parts]) for k in ("scan", "mask", "target"))
        cell, size = sim.data.map_cell, sim.data.map_size
        offset = torch.cat([cell_offsets(b.points, size, cell, device="cpu") for b in parts])
        observed, unobserved = mask > 0, mask == 0
        for label, h in (("mean", scan * mask), ("centred", centre_cells(scan, mask, offset, cell, max_slope=args.gmax, solves=args.iters, span=args.span))):
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
