"""LOADER: the training stream as training pulls it, in-process and with generator worker
processes -> ``pairs_per_s`` per worker count."""

from __future__ import annotations

import time
from collections.abc import Iterable

from ..data.stream import training_batches
from ..sim import resolve_device
from ..training.config import RunConfig
from .harness import SEED, workload_result


def _loader_run(sim, batch: int, count: int, workers: int, device: str) -> dict:
    """``count`` batches pulled from the stream after one untimed start-up batch."""
    it = training_batches(sim, batch, seed=SEED, rank=0, start=0, stop=count + 1, device=device, workers=workers, prefetch=4)
    next(it)  # start-up (process spawn, kernel load) excluded
    t = time.perf_counter()
    for _ in range(count):
        next(it)
    dt = time.perf_counter() - t
    del it
    return {"workers": workers, "batches": count, "seconds": dt, "pairs_per_s": batch * count / dt}


def bench_loader(device=None, quick: bool = False, workers: Iterable[int] = (0, 1, 2), batch: int = 8) -> dict:
    """The training stream (default data, batch 8) as training pulls it: in-process and with
    generator worker processes (CPU only; on CUDA generation stays in-process)."""
    device = resolve_device(device)
    sim = RunConfig().sim()
    count = 2 if quick else 12
    runs = [_loader_run(sim, batch, count, int(n), device) for n in (workers if device == "cpu" else (0,))]
    params = {"batch": batch, "lidar": sim.lidar.name, "map_size": sim.data.map_size, "seed": SEED}
    return workload_result("loader", device, params, runs=runs, pairs_per_s={str(r["workers"]): r["pairs_per_s"] for r in runs})
