"""What the bound on observed cells costs the obstacle and pit scores (stop 38): per set, the
shipped file's obstacle IoU (or pit recall) checked and unchecked, with its observed cells set to
the truth and to the scan's own heights; then the IoU and the observed and unobserved RMSE with
the bound widened to K times each scan's noise (``model.observed_bound_noise``), no training.

usage: python tools/probes/observed_bound.py [--size N] [--factors 0,2,3,4,6]
"""

import argparse

import torch

from warp_terrain.evaluation.metrics import masked_rmse, obstacle_iou, pit_recall
from warp_terrain.evaluation.testsets import make_eval_set
from warp_terrain.inference.reconstructor import Reconstructor

SPLIT_SETS = (("flat_cylinders", 0.0), ("flat_cylinders", 0.05), ("flat_cylinders", 0.1), ("negative_obstacles", 0.0),
              ("negative_obstacles", 0.1))
FACTOR_SETS = (("flat_cylinders", 0.1), ("flat_cylinders", 0.05), ("octave5", 0.1), ("negative_obstacles", 0.1))


def score(ts, height):
    if ts.positive:
        return "IoU", obstacle_iou(height, ts.target, ts.ground)
    if ts.negative:
        return "pit recall", pit_recall(height, ts.target, ts.ground)
    return "-", float("nan")


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--size", type=int, default=16)
    parser.add_argument("--factors", default="0,2,3,4,6")
    args = parser.parse_args()
    print("| set | score | checked | unchecked | observed cells true (checked) | observed cells the scan's (checked) |")
    print("|---|---|---:|---:|---:|---:|")
    for terrain, noise in SPLIT_SETS:
        ts = make_eval_set(terrain, noise, size=args.size, device="cpu")
        observed = ts.mask > 0
        row = []
        for check in (True, False):
            rec = Reconstructor.load(None, device="cpu", self_check=check)
            rec.generator.noise_bound = 0.0  # the bound as trained: 10 cm
            with torch.inference_mode():
                height = rec.predict_maps(ts.scan, ts.mask)
            if check:
                checked = height
            row.append(score(ts, height)[1])
        name = score(ts, checked)[0]
        true_obs = score(ts, torch.where(observed, ts.target, checked))[1]
        scan_obs = score(ts, torch.where(observed, ts.scan, checked))[1]
        print(f"| {terrain}/{noise} | {name} | {row[0]:.3f} | {row[1]:.3f} | {true_obs:.3f} | {scan_obs:.3f} |", flush=True)
    print()
    print("| K | set | score | RMSE unobserved | RMSE observed | the scan's own |")
    print("|---:|---|---:|---:|---:|---:|")
    for factor in (float(k) for k in args.factors.split(",")):
        rec = Reconstructor.load(None, device="cpu")
        rec.generator.noise_bound = factor
        for terrain, noise in FACTOR_SETS:
            ts = make_eval_set(terrain, noise, size=args.size, device="cpu")
            with torch.inference_mode():
                height = rec.predict_maps(ts.scan, ts.mask)
            observed = ts.mask > 0
            name, value = score(ts, height)
            print(f"| {factor:g} | {terrain}/{noise} | {name} {value:.3f} | {masked_rmse(height, ts.target, ~observed):.4f} | "
                  f"{masked_rmse(height, ts.target, observed):.4f} | {masked_rmse(ts.scan, ts.target, observed):.4f} |", flush=True)


if __name__ == "__main__":
    main()
