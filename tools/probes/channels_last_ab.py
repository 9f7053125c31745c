"""The shipped generator's network on one checked map (a batch of two: the scan and its thinned
copy), its weights in the plain layout against channels-last (what ``Reconstructor`` uses on the
CPU), timed in alternating rounds so that a noisy machine weighs on both alike.

    python tools/probes/channels_last_ab.py THREADS
"""

import copy
import sys
import time

import numpy as np
import torch

from warp_terrain.inference.reconstructor import Reconstructor


def main(threads: int, rounds: int = 10, calls: int = 10) -> None:
    torch.set_num_threads(threads)
    nets = {"channels-last": Reconstructor.load(device="cpu", tta=False).generator.net.eval()}
    nets["plain"] = copy.deepcopy(nets["channels-last"]).to(memory_format=torch.contiguous_format)
    x = torch.randn(2, 2, 121, 121)
    times = {name: [] for name in nets}
    with torch.inference_mode():
        torch.testing.assert_close(nets["plain"](x), nets["channels-last"](x), rtol=1e-5, atol=1e-5)
        for _ in range(rounds):
            for name, net in nets.items():
                for _ in range(calls):
                    t = time.perf_counter()
                    net(x)
                    times[name].append(time.perf_counter() - t)
    for name, ts in times.items():
        ms = np.array(ts) * 1e3
        print(f"{threads} thread(s)  {name}: min {ms.min():.1f} ms, median {np.median(ms):.1f} ms ({len(ms)} calls)")


if __name__ == "__main__":
    main(int(sys.argv[1]))
