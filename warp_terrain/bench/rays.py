"""RAYS: an HDL-64E-like scan (64 x 2048 rays) over a 512x512, 0.1 m fBm heightfield ->
``rays_per_s`` and the hit fraction through the public ``cast_scans`` (on the CPU its default
threads, ``sim/threads.py``), on the CPU also on one thread and split over processes, with the
Open3D anchor (:mod:`.anchors`)."""

from __future__ import annotations

import os

import numpy as np
import warp as wp

from ..sim import TerrainConfig, lidar_preset, resolve_device
from ..sim.parallel import ProcessTracer
from ..sim.scan import THREAD_MIN_RAYS, cast_scans, trace
from ..sim.terrain import make_heightfields
from ..sim.threads import split_threads
from .anchors import rays_anchor
from .harness import SEED, summarize, time_calls, workload_result


def _rays_lidar(columns: int):
    """The RAYS sensor: HDL-64E elevations, ``columns`` azimuths, no range noise, no dropout."""
    return lidar_preset("hdl64e", azimuth_step_deg=360.0 / columns, range_noise_std=0.0, dropout=0.0)


def bench_rays(device=None, quick: bool = False, repeats: int | None = None, anchor: bool = True) -> dict:
    """HDL-64E-like scan (64 rings x 2048 columns) over a 512x512, 0.1 m fBm heightfield; with
    the Open3D ``RaycastingScene`` anchor on the same triangles and rays where it is installed.

    The heightfield exists before the clock starts; the per-call max-height tile build inside
    the cast is timed, as it is part of every cast on a fresh terrain. The main figure is what a
    user gets from ``cast_scans`` (its default threads on the CPU); ``one_thread`` is the same
    scan as one launch."""
    device = resolve_device(device)
    size, cell = (128, 0.1) if quick else (512, 0.1)
    columns = 256 if quick else 2048
    repeats = repeats or (2 if quick else 5)
    lidar = _rays_lidar(columns)
    terrain = TerrainConfig(name="bench", octaves=5, feature_size=16.0, amplitude=1.5, cell=cell)
    terrain.validate()
    heights = make_heightfields(1, size, terrain, SEED, device)
    wp.synchronize_device(device)
    heights_torch = wp.to_torch(heights)  # what a user hands cast_scans (zero-copy)
    threads = split_threads(None, lidar.num_rays, THREAD_MIN_RAYS, device)
    out = {}

    def run():  # cast_scans: rays run to the heightfield's edge (reach 0), as on the anchor's mesh
        out["points"] = cast_scans(heights_torch, cell, lidar, SEED, device)

    def run_one_thread():
        out["one_thread"], out["sensor_z"] = trace(heights, cell, lidar, SEED, device, reach=0.0)

    timing = summarize(time_calls(run, device, repeats))
    points = out["points"].cpu().numpy().reshape(-1, 3)
    hits = float(np.isfinite(points[:, 0]).mean())
    rays = lidar.num_rays
    rays_per_s = rays / timing["median_s"]
    params = {"api": "cast_scans", "threads": threads, "lidar": lidar.name, "channels": lidar.channels, "columns": lidar.columns, "rays": rays,
              "mount_height_m": lidar.mount_height, "max_range_m": lidar.max_range,
              "size": size, "cell_m": cell, "extent_m": (size - 1) * cell, "octaves": terrain.octaves,
              "feature_size_m": terrain.feature_size, "amplitude_m": terrain.amplitude, "seed": SEED}
    result = workload_result("rays", device, params, **timing, rays_per_s=rays_per_s, hit_fraction=hits)
    if device == "cpu" and threads > 1:
        one = summarize(time_calls(run_one_thread, device, repeats))
        same = bool(np.array_equal(out["one_thread"].numpy().reshape(-1, 3), points, equal_nan=True))
        result["one_thread"] = {**one, "rays_per_s": rays / one["median_s"], "equal_to_threads": same}
    else:
        run_one_thread()
    if device == "cpu" and not quick and (os.cpu_count() or 1) > 1:
        result["processes"] = _rays_processes(heights.numpy(), cell, lidar, points, repeats)
    if anchor:
        sensor_z = float(out["sensor_z"].numpy()[0])
        distances = np.linalg.norm(points.astype(np.float64), axis=1)  # sensor frame, no augmentation: |p| = t
        result["anchor"] = rays_anchor(heights.numpy()[0], cell, lidar, sensor_z, distances, rays_per_s, repeats)
        _add_processes_over_anchor(result.get("processes"), result["anchor"])
    return result


def _add_processes_over_anchor(procs: dict | None, anchor: dict) -> None:
    """Each anchor timing gets the process split's throughput over its own, when both exist."""
    if not procs or not anchor.get("available"):
        return
    for run in anchor["runs"]:
        for kind in ("cast", "fresh"):
            run[kind]["processes_over_anchor"] = procs["rays_per_s"] / run[kind]["rays_per_s"]


def _rays_processes(heights: np.ndarray, cell: float, lidar, single: np.ndarray, repeats: int) -> dict:
    """The same scan split by azimuth columns over one process per core (``sim/parallel.py``)."""
    processes = min(os.cpu_count() or 1, 8)
    with ProcessTracer(heights, cell, lidar, seed=SEED, processes=processes, reach=0.0) as tracer:
        times = time_calls(tracer.cast, "cpu", repeats)
        same = bool(np.array_equal(tracer.cast().reshape(single.shape), single, equal_nan=True))
    timing = summarize(times)
    return {"processes": processes, **timing, "rays_per_s": lidar.num_rays / timing["median_s"], "equal_to_one_process": same}
