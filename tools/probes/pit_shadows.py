"""Where the self-check loses the pits: the paper's pit setting, pit cells versus the scan's shadows.

usage: python tools/probes/pit_shadows.py [--size N] [--margin M]

On ``negative_obstacles`` (clean, the suite's maps) it prints, for the pit cells (unobserved,
true height more than 0.3 m below the bare ground): the share the shadow test
(``inference/shadows.shadow_cells``) flags when it is given the thin-plate fill (as the
self-check does) and when given the unchecked net's prediction; and the RMSE on those cells of
the thin plate, the shipped file unchecked and checked. Not part of the package or the suite.
"""

import argparse

import torch

from warp_terrain.evaluation.metrics import OBSTACLE_THRESHOLD, masked_rmse
from warp_terrain.evaluation.testsets import make_eval_set
from warp_terrain.inference.predictor import reconstructor_predictor
from warp_terrain.inference.reconstructor import Reconstructor
from warp_terrain.inference.shadows import shadow_cells
from warp_terrain.models.biharmonic import biharmonic_fill


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=32)
    parser.add_argument("--margin", type=float, default=0.05, help="metres the horizon is lowered by")
    args = parser.parse_args()
    torch.set_num_threads(1)
    ts = make_eval_set("negative_obstacles", 0.0, size=args.size, device="cpu")
    unobserved = ts.mask < 0.5
    pits = unobserved & ((ts.ground - ts.target) > OBSTACLE_THRESHOLD)  # pit_recall's pit cells
    thin_plate = biharmonic_fill(ts.scan, ts.mask)
    raw = reconstructor_predictor(Reconstructor.load(None, device="cpu", self_check=False))(ts.scan, ts.mask)
    checked = reconstructor_predictor(Reconstructor.load(None, device="cpu", self_check=True))(ts.scan, ts.mask)
    raw, checked = (out[0] if isinstance(out, tuple) else out for out in (raw, checked))
    n = int(pits.sum())
    print(f"{n} pit cells of {int(unobserved.sum())} unobserved ({args.size} maps)")
    for name, fill in (("thin plate", thin_plate), ("net unchecked", raw.float())):
        flagged = shadow_cells(ts.scan, ts.mask, fill, args.margin) & pits
        print(f"shadow test given the {name:13s}: {100 * int(flagged.sum()) / n:5.1f} % of pit cells in shadow")
    for name, pred in (("thin plate", thin_plate), ("net unchecked", raw.float()), ("net checked", checked.float())):
        print(f"RMSE on pit cells, {name:13s}: {masked_rmse(pred, ts.target, pits):.4f} m; "
              f"on the other unobserved cells {masked_rmse(pred, ts.target, unobserved & ~pits):.4f} m")


if __name__ == "__main__":
    main()
