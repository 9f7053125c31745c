"""Per set, how many maps the shipped self-check cannot resolve (too few hidden cells, or checked
errors under the scan's noise; near the scan and far from it), how many of their unobserved
cells lie within 1 sigma at the file's fallback factor, and the factor that would put 68 % of
them there (on the raw sigma, as ``sigma_scale`` is); then the same on the run's own validation
world (the calibration pairs), pooled: what ``fit_unresolved_sigma_scale`` fits (stop 38).

usage: python tools/probes/sigma_unresolved.py [--size N] [--model PATH]
"""

import argparse

import torch

from warp_terrain.data.stream import make_pair, validation_seed
from warp_terrain.evaluation.calibrate import CALIBRATION_FIRST_CHUNK
from warp_terrain.evaluation.testsets import make_eval_set
from warp_terrain.inference.reconstructor import Reconstructor
from warp_terrain.inference.selfcheck import SIGMA_COVERAGE
from warp_terrain.sim import as_sim_config


def unresolved_ratios(rec, scan, mask, target):
    """(maps, unresolved maps, |error| / raw sigma on the cells where the fallback applies)."""
    with torch.inference_mode():
        checked = rec.check_maps(scan, mask)
    (_, near), (_, away) = checked.factors
    far = checked.regimes.far(mask) >= 0.5
    cells = ((~near.view(-1, 1, 1, 1) & ~far) | (~away.view(-1, 1, 1, 1) & far)) & (mask <= 0)
    raw = checked.sigma / rec.sigma_scale
    return len(near), int((~near | ~away).sum()), ((checked.height - target).abs() / raw)[cells].float()


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--size", type=int, default=16)
    parser.add_argument("--model", default=None, help="a Reconstructor file (default: the shipped one)")
    args = parser.parse_args()
    rec = Reconstructor.load(args.model, device="cpu")
    fallback = rec.meta.get("sigma_scale_unresolved", rec.sigma_scale)
    print(f"sigma_scale {rec.sigma_scale:.4f}, fallback {fallback:.4f}")
    print("| set | maps unresolved | their cells within 1 sigma at the fallback | factor for 68 % |")
    print("|---|---:|---:|---:|")
    for terrain in ("octave3", "octave5", "flat_cylinders", "negative_obstacles"):
        for noise in (0.0, 0.05, 0.1):
            ts = make_eval_set(terrain, noise, size=args.size, device="cpu")
            n, bad, r = unresolved_ratios(rec, ts.scan, ts.mask, ts.target)
            inside = f"{float((r <= fallback).float().mean()):.3f}" if r.numel() else "-"
            k = f"{float(torch.quantile(r.double(), SIGMA_COVERAGE)):.3f}" if r.numel() else "-"
            print(f"| {terrain}/{noise} | {bad} of {n} | {inside} | {k} |", flush=True)
    sim = as_sim_config({key: rec.meta["config"][key] for key in ("terrain", "lidar", "data")})
    pooled, total, bad = [], 0, 0
    for i in range(max(1, args.size // 4)):
        pair = make_pair(sim, 16, validation_seed(CALIBRATION_FIRST_CHUNK + i), "cpu")
        n, b, r = unresolved_ratios(rec, pair["scan"], pair["mask"], pair["target"])
        pooled.append(r)
        total, bad = total + n, bad + b
    r = torch.cat(pooled)
    print(f"| the run's validation world (calibration pairs) | {bad} of {total} | {float((r <= fallback).float().mean()):.3f} | "
          f"{float(torch.quantile(r.double(), SIGMA_COVERAGE)):.3f} |")


if __name__ == "__main__":
    main()
