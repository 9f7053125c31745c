"""Real data the suite does not score and the shipped model never saw: a generalisation check.

    THREADS=2 python tools/probes/unseen_real.py [--only WORD] [NAME=MODEL ...]
    (default: shipped_check_reach_keepfar_sigma_membrane=shipped, the file as it ships)

Families: the seven Ouster sweeps `make real-data` fetches for training only (`train_ouster_*`:
other sensors and serial numbers than the suite's OS-1 and OS-2; no shipped recipe trains on
them), each scored as the suite scores its real scans (a fifth of the observed cells hidden, 3
repeats), and the suite's real rasters at other scales than the suite's and the training's
(mammoth 1:2, Finland 1:10, Jacksboro 1:40: other slopes and feature sizes). Prints each model's
unobserved RMSE over the best classical fill's and its share of scored cells within 1 sigma
(``real_ablation.report``: per family, then as table rows).
NAME and MODEL as in tools/real_ablation.py (the name's tokens pick the check); `--only WORD`
scores only the families whose name holds WORD (repeatable).
"""

import argparse
import os
import sys

import torch

from warp_terrain.evaluation import real
from warp_terrain.evaluation.baselines import BASELINES
from warp_terrain.evaluation.real import RealFamily, evaluate_real

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
import real_ablation  # noqa: E402

SCANS = ("os0_128_u1", "os0_128_single", "os0_32_u1", "os1_32_g", "os2_32_u0", "os1_128_rig_s0", "os1_128_rig_s1")
DEMS = (
    RealFamily("mammoth, rescaled 1:2", "dem", ("mammoth_dem.tif",), scale=0.5),
    RealFamily("finland, rescaled 1:10", "dem", ("finland_topography_dem.tif",), scale=0.1),
    RealFamily("jacksboro, rescaled 1:40", "dem", ("jacksboro_dem.tif",), scale=1 / 40),
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", action="append", default=[], help="score only families whose name holds this")
    parser.add_argument("models", nargs="*", default=["shipped_check_reach_keepfar_sigma_membrane=shipped"])
    args = parser.parse_args()
    torch.set_num_threads(int(os.environ.get("THREADS", "1")))
    keep = (lambda f: any(w in f.name for w in args.only)) if args.only else (lambda f: True)
    scans = tuple(RealFamily(f"Ouster {s} (unseen)", "scan", (f"train_ouster_{s}_f0.npz",)) for s in SCANS)
    # a family left out names a file that is not there, so the suite skips it and every other
    # keeps its seed (its index)
    real.DEM_FAMILIES = tuple(f if keep(f) else RealFamily(f.name, f.kind, ("left out",)) for f in DEMS)
    real.SCAN_FAMILIES = tuple(f if keep(f) else RealFamily(f.name, f.kind, ("left out",)) for f in scans)
    nets = real_ablation.models(args.models)
    results = evaluate_real({**BASELINES, **nets}, size=32, repeats=3, device="cpu", synthetic=False,
                            progress=lambda line: "left out" in line or print(line, flush=True))
    real_ablation.report(results, {}, list(nets))

if __name__ == "__main__":
    main()
