"""Probe (docs/transfer.md): each model's obstacle IoU (flat ground with cylinders)
and pit recall (pits and ditches), with its unobserved-cell RMSE beside the best classical fill's,
checked as the shipped file is and unchecked; 8-orientation average as `evaluate`.

    python tools/probes/obstacle_scores.py [--size N] NAME=MODEL ...

MODEL: a checkpoint or a Reconstructor file, or `shipped`. Also the error inside the obstacles:
the RMSE and the mean error (prediction - truth) on the unobserved obstacle cells (more than 0.3 m
above / below the bare ground), where a fill that does not see into a pit errs high.
"""

import argparse

import torch
from common import load_checked

from warp_terrain.evaluation.baselines import BASELINES
from warp_terrain.evaluation.metrics import OBSTACLE_THRESHOLD, masked_rmse, obstacle_iou, pit_recall
from warp_terrain.evaluation.testsets import make_eval_set

SETTINGS = ("flat_cylinders", "negative_obstacles")
NOISES = (0.0, 0.1)


def scores(pred: torch.Tensor, ts, setting: str) -> str:
    unobserved = ts.mask < 0.5
    negative = setting == "negative_obstacles"
    inside = unobserved & ((ts.ground - ts.target) > OBSTACLE_THRESHOLD if negative else (ts.target - ts.ground) > OBSTACLE_THRESHOLD)
    found = (pit_recall if negative else obstacle_iou)(pred, ts.target, ts.ground)
    error = (pred - ts.target)[inside]
    return (f"RMSE {masked_rmse(pred, ts.target, unobserved):.4f}  {'pit recall' if negative else 'IoU'} {found:.3f}  "
            f"inside: RMSE {error.square().mean().sqrt():.3f} mean {error.mean():+.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=32)
    parser.add_argument("models", nargs="+", help="NAME=MODEL")
    args = parser.parse_args()
    torch.set_num_threads(1)
    for setting in SETTINGS:
        for noise in NOISES:
            ts = make_eval_set(setting, noise, size=args.size, device="cpu")
            fills = {name: BASELINES[name](ts.scan, ts.mask) for name in ("biharmonic", "harmonic")}
            for name, pred in fills.items():
                print(f"{setting}/{noise} {name:18s} {scores(pred.float(), ts, setting)}", flush=True)
            for arg in args.models:
                name, path = arg.split("=", 1)
                for checked in (True, False):
                    with torch.inference_mode():
                        pred = load_checked(path, self_check=checked).predict_maps(ts.scan, ts.mask).float()
                    label = f"{name}{'' if checked else ' unchecked'}"
                    print(f"{setting}/{noise} {label:18s} {scores(pred, ts, setting)}", flush=True)


if __name__ == "__main__":
    main()
