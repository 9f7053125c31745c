"""On the real suite's scans (20 % of observed cells hidden, 3 draws, as `evaluate --real`): each
model's net alone and checked, scored on the hidden cells, and the weight the self-check gives
the net's correction next to the scan (median and mean over maps). No orientation average.

    python tools/probes/scan_check_weights.py NAME=MODEL ...

MODEL: a checkpoint or a Reconstructor file, or `shipped`; every model is checked as the shipped
file is (reach, membrane, keep-far, sigma). Needs `make real-data`.
"""

import sys
from pathlib import Path

import torch
from common import load_checked

from warp_terrain.evaluation.real import MAP, REAL_SEED_BASE, SCAN_FAMILIES, scan_family_set
from warp_terrain.inference.reconstructor import Reconstructor
from warp_terrain.inference.selfcheck import Regimes, check_cells, checked_fills


def near_weight(rec: Reconstructor, scan: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(net's maps of the full scans, the check's near weight per map), as ``checked_maps`` weighs."""
    hidden, outer, thinned = check_cells(mask)
    n = scan.shape[0]
    heights, _, fills = rec._predict(torch.cat([scan, scan * thinned]), torch.cat([mask, thinned]), rec.check_tensions)
    regimes = Regimes(hidden, outer)
    _, fill = checked_fills(fills, scan, mask, thinned, regimes, rec.check_membrane)
    return heights[:n], regimes.weight(heights[n:], fill, scan)[0].flatten()


def main(args: list[str]) -> None:
    torch.set_num_threads(1)
    models = {name: load_checked(path, tta=False) for name, path in (arg.split("=", 1) for arg in args)}
    for i, family in enumerate(SCAN_FAMILIES):
        ss = scan_family_set(family, Path("real_data"), 3, MAP.size, MAP.cell, REAL_SEED_BASE + 100 + i)
        for name, rec in models.items():
            with torch.inference_mode():
                net, w = near_weight(rec, ss.scan, ss.mask)
                checked, _ = rec._predict_checked(ss.scan, ss.mask)
            rmse = [float((m - ss.measured)[ss.hidden].square().mean().sqrt()) for m in (net, checked)]
            print(f"{family.name[:34]:<34} {name:<6} near weight median {w.median():.2f} mean {w.mean():.2f} | "
                  f"hidden-cell RMSE net alone {rmse[0]:.4f} m, checked {rmse[1]:.4f} m", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
