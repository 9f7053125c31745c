"""Why the checked sigma is too wide on clean, smooth ground: the check scales each map's sigma
on the heights the scan measured in its hidden cells, and a measured cell height is not the
ground's height at the cell centre (the points of a cell lie off its centre; on a slope their
mean is off by slope x offset). This probe predicts each set twice with the shipped model, once
from the scan and once from the scan with its observed cells replaced by the true heights, and
prints per set: the scan's own RMSE on observed cells and the noise ``scan_noise`` estimates,
each run's share of unobserved cells within 1 sigma, and the median sigma factor.

``--walls`` prints instead, per synthetic setting, the observed cells whose measured height is
more than 0.3 m off the true one (a pit's far wall, a cylinder's side): their share, their share
of the scan's squared error on observed cells, and how they err (no model).

``--no-resolution`` measures every map's factor, as stops 31-32 did, even where the checked errors
do not stand out of the scan's noise (``selfcheck.SIGMA_RESOLUTION``; with the rule such a map
keeps k = 1, and with true heights in almost every map is such a map).

usage: python tools/probes/sigma_truth.py [--size N] [--notta] [--walls] [--no-resolution]
"""

import argparse

import torch
from common import load_checked

import warp_terrain.inference.reconstructor as reconstructor
from warp_terrain.evaluation.real import DEM_FAMILIES, dem_family_set, real_data_dir
from warp_terrain.evaluation.testsets import make_eval_set
from warp_terrain.inference.selfcheck import scan_noise, sigma_factor

FACTORS: list[torch.Tensor] = []


RESOLUTION: dict = {}


def recording(*args, **kwargs):
    k = sigma_factor(*args, **kwargs, **RESOLUTION)
    FACTORS.append(k.flatten())
    return k


def coverage(rec, scan, mask, target):
    FACTORS.clear()
    heights, sigmas = [], []
    for i in range(0, scan.shape[0], 16):
        h, s = rec.predict_maps_with_uncertainty(scan[i:i + 16], mask[i:i + 16])
        heights.append(h)
        sigmas.append(s)
    height, sigma = torch.cat(heights), torch.cat(sigmas)
    unobserved = mask == 0
    within = ((height - target).abs() <= sigma)[unobserved].float().mean()
    rmse = ((height - target)[unobserved] ** 2).mean().sqrt()
    return float(within), float(rmse), float(torch.cat(FACTORS).median())


def walls(size: int) -> None:
    for terrain in ("negative_obstacles", "flat_cylinders", "octave3"):
        ts = make_eval_set(terrain, 0.0, size=size, device="cpu")
        error = (ts.scan - ts.target)[ts.mask > 0]
        off = error.abs() > 0.3
        if not bool(off.any()):
            print(f"{terrain}: no observed cell more than 0.3 m off")
            continue
        print(f"{terrain}: {int(off.sum())} of {error.numel()} observed cells ({float(off.float().mean()):.2%}) more than 0.3 m off, "
              f"{float((error[off] ** 2).sum() / (error ** 2).sum()):.0%} of the squared error; "
              f"{float((error[off] > 0).float().mean()):.0%} of them above the truth, by {float(error[off].mean()):+.2f} m on average")


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--size", type=int, default=32)
    parser.add_argument("--notta", action="store_true")
    parser.add_argument("--walls", action="store_true")
    parser.add_argument("--no-resolution", action="store_true")
    args = parser.parse_args()
    if args.no_resolution:
        RESOLUTION["resolution"] = float("-inf")
    if args.walls:
        return walls(args.size)
    reconstructor.sigma_factor = recording
    rec = load_checked("shipped", tta=not args.notta)
    sets = [(f"{t}/noise{n}", make_eval_set(t, n, size=args.size, device="cpu"))
            for t, n in (("octave3", 0.0), ("octave5", 0.0), ("flat_cylinders", 0.0), ("negative_obstacles", 0.0), ("octave3", 0.1))]
    folder = real_data_dir()
    sets += [(f.name, dem_family_set(f, folder, args.size, "cpu")) for f in DEM_FAMILIES]
    print("| set | scan RMSE on observed | scan_noise median | within 1 sigma (k median) | true heights in: within 1 sigma (k median) | RMSE scan / truth in |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, ts in sets:
        observed = ts.mask > 0
        scan_err = float(((ts.scan - ts.target)[observed] ** 2).mean().sqrt())
        noise = float(scan_noise(ts.scan, ts.mask).median())
        a = coverage(rec, ts.scan, ts.mask, ts.target)
        b = coverage(rec, ts.target * ts.mask, ts.mask, ts.target)
        print(f"| {name} | {scan_err:.4f} | {noise:.4f} | {a[0]:.0%} ({a[2]:.2f}) | {b[0]:.0%} ({b[2]:.2f}) | {a[1]:.4f} / {b[1]:.4f} |", flush=True)


if __name__ == "__main__":
    main()
