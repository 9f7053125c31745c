"""NOISE: fBm heightfields (64 of 121x121, 5 octaves) -> ``samples_per_s``, on the CPU also
split over processes, with the pyfastnoiselite anchor (:mod:`.anchors`)."""

from __future__ import annotations

import os

import numpy as np

from ..sim import TerrainConfig, resolve_device
from ..sim.parallel import ProcessHeightfields
from ..sim.terrain import make_heightfields
from .anchors import noise_anchor
from .harness import SEED, summarize, time_calls, workload_result


def bench_noise(device=None, quick: bool = False, repeats: int | None = None, anchor: bool = True) -> dict:
    """fBm heightfields: 64 terrains of 121x121 vertices, 5 octaves, no obstacles; with the
    pyfastnoiselite anchor on the same number of fBm samples where it is installed."""
    device = resolve_device(device)
    batch, size = (8, 33) if quick else (64, 121)
    repeats = repeats or (2 if quick else 5)
    cfg = TerrainConfig(name="bench", octaves=5, feature_size=8.0, amplitude=1.5, cell=0.25)
    cfg.validate()

    out = {}

    def run():
        out["heights"] = make_heightfields(batch, size, cfg, SEED, device)

    timing = summarize(time_calls(run, device, repeats))
    samples_per_s = batch * size * size / timing["median_s"]
    params = {"batch": batch, "size": size, "cell_m": cfg.cell, "octaves": cfg.octaves,
              "feature_size_m": cfg.feature_size, "amplitude_m": cfg.amplitude, "seed": SEED}
    result = workload_result(
        "noise", device, params, **timing,
        heightfields_per_s=batch / timing["median_s"],
        samples_per_s=samples_per_s,  # fBm values (vertices), as the anchors count them
    )
    if device == "cpu" and not quick and (os.cpu_count() or 1) > 1:
        result["processes"] = _noise_processes(batch, size, cfg, out["heights"].numpy(), repeats)
    if anchor:
        result["anchor"] = noise_anchor(batch, size, cfg, repeats, samples_per_s)
        procs = result.get("processes")
        if procs and result["anchor"].get("available"):
            result["anchor"]["processes_over_anchor"] = procs["samples_per_s"] / result["anchor"]["samples_per_s"]
    return result


def _noise_processes(batch: int, size: int, cfg: TerrainConfig, single: np.ndarray, repeats: int) -> dict:
    """The same heightfields split by samples over one process per core (``sim/parallel.py``)."""
    processes = min(os.cpu_count() or 1, 8)
    with ProcessHeightfields(batch, size, cfg, seed=SEED, processes=processes) as terrains:
        times = time_calls(terrains.make, "cpu", repeats)
        same = bool(np.array_equal(terrains.make(), single))
    timing = summarize(times)
    return {"processes": processes, **timing, "samples_per_s": batch * size * size / timing["median_s"], "equal_to_one_process": same}
