"""STREAM: ``generate_batch(B, SimConfig())`` (HDL-32E, 121x121 maps) -> ``pairs_per_s``, with
a breakdown into terrain, ray cast and projection + ground truth, each stage timed on its own."""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterable

from ..sim import SimConfig, generate_batch, resolve_device
from ..sim.batch import make_maps, make_terrains, scan_terrains, terrain_size
from .harness import SEED, summarize, time_calls, workload_result


def _stream_stages(batch: int, sim: SimConfig, device: str, repeats: int) -> dict:
    """Median seconds of each of ``generate_batch``'s stages, timed separately."""
    seed = SEED & 0x7FFFFFFF
    state = {}

    def terrain():
        state["heights"] = make_terrains(batch, sim, seed, device)

    def cast():
        state["points"], state["sensor_z"] = scan_terrains(state["heights"], sim, seed, device)

    def maps():
        make_maps(state["heights"], state["points"], state["sensor_z"], sim, seed, device)

    stages = {}
    for name, fn in (("terrain", terrain), ("ray_cast", cast), ("projection_truth", maps)):
        stages[name] = float(statistics.median(time_calls(fn, device, repeats)))
    return stages


def _stream_run(batch: int, sim: SimConfig, device: str, repeats: int) -> dict:
    """One batch size: ``generate_batch`` timed whole, then its stages one by one."""
    timing = summarize(time_calls(lambda: generate_batch(batch, sim, seed=SEED, device=device), device, repeats))
    stages = _stream_stages(batch, sim, device, repeats)
    total = sum(stages.values())
    return {
        "batch": batch,
        **timing,
        "pairs_per_s": batch / timing["median_s"],
        "rays_per_s": batch * sim.lidar.num_rays / timing["median_s"],
        "breakdown_s": stages,
        "breakdown_sum_s": total,
        "breakdown_fraction": {k: (v / total if total > 0 else math.nan) for k, v in stages.items()},
    }


def bench_stream(device=None, quick: bool = False, batches: Iterable[int] | None = None, repeats: int | None = None) -> dict:
    """``generate_batch(B, SimConfig())`` for a few batch sizes, with a per-stage breakdown."""
    device = resolve_device(device)
    batches = [int(b) for b in (batches or ((1, 2) if quick else (1, 16)))]
    if any(b < 1 for b in batches):
        raise ValueError(f"batches={batches!r}: every batch size must be >= 1")
    repeats = repeats or (2 if quick else 3)
    sim = SimConfig()
    sim.validate()
    runs = [_stream_run(batch, sim, device, repeats) for batch in batches]
    params = {"batches": batches, "lidar": sim.lidar.name, "rays_per_scan": sim.lidar.num_rays,
              "map_size": sim.data.map_size, "map_cell_m": sim.data.map_cell,
              "terrain": sim.terrain.name, "terrain_size": terrain_size(sim), "terrain_cell_m": sim.terrain.cell,
              "octaves": sim.terrain.octaves, "augment": sim.data.augment, "noise": sim.data.noise,
              "truth_samples": sim.data.truth_samples, "clip_rays": bool(getattr(sim.data, "clip_rays", False)), "seed": SEED}
    return workload_result("stream", device, params, pairs_per_s={str(r["batch"]): r["pairs_per_s"] for r in runs}, runs=runs)
