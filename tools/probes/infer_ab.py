"""One map from a point cloud (no orientation average, each file's own self-check), two model
files timed in alternating rounds so that a noisy machine weighs on both alike.

    python tools/probes/infer_ab.py THREADS A.pt B.pt

e.g. the ngf-16 file shipped before stop 30 against today's:
    git show 88a14bc:warp_terrain/pretrained/reconstructor.pt > /tmp/ngf16.pt
    python tools/probes/infer_ab.py 2 /tmp/ngf16.pt warp_terrain/pretrained/reconstructor.pt
"""

import sys
import time

import numpy as np
import torch

from warp_terrain.bench.harness import SEED
from warp_terrain.inference.reconstructor import Reconstructor
from warp_terrain.sim import generate_batch
from warp_terrain.sim.batch import SimConfig


def main(threads: int, paths: list[str], rounds: int = 4, calls: int = 8) -> None:
    torch.set_num_threads(threads)
    sim = SimConfig()
    sim.validate()
    cloud = generate_batch(4, sim, seed=SEED, device="cpu").points[0].numpy()
    cloud = cloud[np.isfinite(cloud).all(1)]  # the bench's HDL-32E scan, its returns only
    recs = {path: Reconstructor.load(path, device="cpu", tta=False) for path in paths}
    for rec in recs.values():
        for _ in range(3):
            rec.reconstruct(cloud, 121, 0.25)
    times = {path: [] for path in recs}
    for _ in range(rounds):
        for path, rec in recs.items():
            for _ in range(calls):
                t = time.perf_counter()
                rec.reconstruct(cloud, 121, 0.25)
                times[path].append(time.perf_counter() - t)
    for path, ts in times.items():
        ms = np.array(ts) * 1e3
        print(f"{threads} thread(s)  {path}: min {ms.min():.1f} ms, median {np.median(ms):.1f} ms ({len(ms)} calls)")


if __name__ == "__main__":
    main(int(sys.argv[1]), sys.argv[2:])
