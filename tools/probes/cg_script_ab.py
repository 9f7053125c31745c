"""The self-check's classical fills of one map (six maps in one solve: the base fill, the thin
plate and the membrane of the scan and its thinned copy), the CG loop as TorchScript against the
eager loop, timed in alternating rounds; both give the same bits.

    python tools/probes/cg_script_ab.py THREADS
"""

import sys
import time

import numpy as np
import torch

from warp_terrain.models import biharmonic
from warp_terrain.sim import generate_batch
from warp_terrain.sim.batch import SimConfig


def main(threads: int, rounds: int = 10, calls: int = 10) -> None:
    torch.set_num_threads(threads)
    batch = generate_batch(6, SimConfig(), seed=1, device="cpu")
    height, mask = batch.scan.float(), batch.mask.float()
    tension = torch.tensor([0.0, 0.0, 0.0, 0.0, 1.0, 1.0]).view(-1, 1, 1, 1)
    loops = {"eager": biharmonic._eager_cg, "TorchScript": biharmonic.conjugate_gradient}
    times, maps = {name: [] for name in loops}, {}
    try:
        with torch.inference_mode():
            for _ in range(rounds):
                for name, loop in loops.items():
                    biharmonic.conjugate_gradient = loop
                    for _ in range(calls):
                        t = time.perf_counter()
                        maps[name] = biharmonic.biharmonic_fill(height, mask, tension=tension)
                        times[name].append(time.perf_counter() - t)
    finally:
        biharmonic.conjugate_gradient = loops["TorchScript"]
    assert torch.equal(maps["eager"], maps["TorchScript"])
    for name, ts in times.items():
        ms = np.array(ts) * 1e3
        print(f"{threads} thread(s)  {name}: min {ms.min():.1f} ms, median {np.median(ms):.1f} ms ({len(ms)} calls)")


if __name__ == "__main__":
    main(int(sys.argv[1]))
