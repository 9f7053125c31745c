"""Reproducible benchmarks: fixed, seeded workloads timed on one device, with anchors.

Six workloads, each a function returning a plain (JSON-ready) dict:

- :func:`bench_noise` (NOISE): fBm heightfields (64 of 121x121, 5 octaves) -> ``samples_per_s``
  (fBm values). Anchor: pyfastnoiselite (FastNoiseLite Perlin fBm, same octaves, lacunarity,
  gain and first wavelength, one thread) on the same number of samples.
- :func:`bench_rays` (RAYS): an HDL-64E-like scan (64 x 2048 = 131,072 rays) from 1.8 m over a
  512x512, 0.1 m fBm heightfield -> ``rays_per_s`` and the hit fraction. The heightfield exists
  before the clock starts; the per-call max-height tile build inside ``trace`` is timed, as it is
  part of every cast on a fresh terrain. Anchor: Open3D's ``RaycastingScene`` (Embree) on the
  triangle mesh of the same heightfield (same diagonal), cast-only and fresh (BVH build + cast),
  with all threads and one; the hit distances of the two must agree to 1 mm.
- :func:`bench_stream` (STREAM): ``generate_batch(B, SimConfig())`` (HDL-32E, 121x121 maps) ->
  ``pairs_per_s``, with a breakdown into terrain, ray cast and projection + ground truth, each
  stage timed on its own.
- :func:`bench_loader`: the training stream in-process and with generator worker processes.
- :func:`bench_train` (TRAIN): the paper's model (Table 2, ngf 64) -> ``images_per_s`` of
  optimiser steps on a fixed batch (no data time), the same steps pulling batches from the
  training stream (``data_wait_share``), and the channels_last and ``torch.compile`` variants.
- :func:`bench_infer` (INFER): points -> map latency of the shipped ``Reconstructor``, and its
  network under torch and ONNX Runtime (with their max abs difference).

Every timing follows one warm-up call with the same shapes (kernel compilation and module
loading excluded), synchronises the device before reading ``time.perf_counter`` and reports the
median of a few repeats. An anchor that is not installed is reported as such (``available:
false`` and the reason), never as an error. :func:`run_benchmarks` runs a selection and adds the
environment (device, Warp/torch versions); :func:`format_table` renders its result for people.
"""

from __future__ import annotations

import contextlib
import copy
import json
import math
import os
import platform
import queue
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable
from importlib import metadata

import numpy as np
import torch
import warp as wp

from ..core.version import __version__
from ..sim import SimConfig, TerrainConfig, generate_batch, lidar_preset, resolve_device
from ..sim.batch import make_maps, make_terrains, scan_terrains, terrain_size
from ..sim.scan import trace
from ..sim.terrain import make_heightfields

SEED = 12345

__all__ = [
    "BENCHMARKS",
    "bench_infer",
    "bench_loader",
    "bench_noise",
    "bench_rays",
    "bench_stream",
    "bench_train",
    "compare_hits",
    "environment",
    "format_table",
    "heightfield_triangles",
    "open3d_hits",
    "parse_only",
    "run_benchmarks",
]

AGREEMENT_TOLERANCE_M = 1e-3  # RAYS: our hit distances and Open3D's must agree to 1 mm
COMPILE_LIMIT_S = 120.0  # TRAIN: torch.compile gets this long for its first steps, else it is recorded as too slow


# ------------------------------------------------------------------------------- helpers
def _sync(device: str) -> None:
    """Wait for Warp's and torch's work on ``device``."""
    wp.synchronize_device(device)
    if device.startswith("cuda"):
        torch.cuda.synchronize(device)


def _time(fn: Callable[[], object], device: str, repeats: int, warmup: int = 1) -> list[float]:
    """Seconds per call of ``fn`` over ``repeats`` calls, after ``warmup`` untimed calls."""
    for _ in range(warmup):
        fn()
    _sync(device)
    times = []
    for _ in range(repeats):
        _sync(device)
        t0 = time.perf_counter()
        fn()
        _sync(device)
        times.append(time.perf_counter() - t0)
    return times


def _unavailable(module: str, err: BaseException) -> dict:
    """An anchor that cannot run here: reported, not raised."""
    return {"available": False, "reason": f"{module} not importable ({type(err).__name__}: {' '.join(str(err).split())})"}


def _version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "unknown"


@contextlib.contextmanager
def _torch_threads(n: int):
    """torch's intra-op thread count set to ``n`` for the block, then restored."""
    before = torch.get_num_threads()
    torch.set_num_threads(int(n))
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _timing(times: list[float]) -> dict:
    return {
        "median_s": float(statistics.median(times)),
        "min_s": float(min(times)),
        "repeats": len(times),
        "times_s": [float(t) for t in times],
    }


def _device_name(device: str) -> str:
    if device.startswith("cuda"):
        return str(wp.get_device(device).name)
    model = ""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return model or platform.processor() or platform.machine() or "CPU"


def environment(device=None) -> dict:
    """Where the numbers come from: device, its name, and the software versions."""
    device = resolve_device(device)
    return {
        "device": device,
        "device_name": _device_name(device),
        "cpu_count": os.cpu_count(),
        "warp": wp.config.version,
        "torch": torch.__version__,
        "python": platform.python_version(),
        "warp_terrain": __version__,
        "platform": platform.platform(),
    }


def _result(name: str, device: str, params: dict, **values) -> dict:
    env = environment(device)
    return {"workload": name, "params": params, "device": device, "device_name": env["device_name"],
            "warp": env["warp"], "torch": env["torch"], **values}


# ------------------------------------------------------------------------------- workloads
def bench_noise(device=None, quick: bool = False, repeats: int | None = None, anchor: bool = True) -> dict:
    """fBm heightfields: 64 terrains of 121x121 vertices, 5 octaves, no obstacles; with the
    pyfastnoiselite anchor on the same number of fBm samples where it is installed."""
    device = resolve_device(device)
    batch, size = (8, 33) if quick else (64, 121)
    repeats = repeats or (2 if quick else 5)
    cfg = TerrainConfig(name="bench", octaves=5, feature_size=16.0, amplitude=1.5, cell=0.25)
    cfg.validate()

    out = {}

    def run():
        out["heights"] = make_heightfields(batch, size, cfg, SEED, device)

    times = _time(run, device, repeats)
    timing = _timing(times)
    samples_per_s = batch * size * size / timing["median_s"]
    params = {"batch": batch, "size": size, "cell_m": cfg.cell, "octaves": cfg.octaves,
              "feature_size_m": cfg.feature_size, "amplitude_m": cfg.amplitude, "seed": SEED}
    result = _result(
        "noise", device, params, **timing,
        heightfields_per_s=batch / timing["median_s"],
        samples_per_s=samples_per_s,  # fBm values (vertices), as the anchors count them
    )
    if device == "cpu" and not quick and (os.cpu_count() or 1) > 1:
        result["processes"] = _noise_processes(batch, size, cfg, out["heights"].numpy(), repeats)
    if anchor:
        result["anchor"] = _noise_anchor(batch, size, cfg, repeats, samples_per_s)
        procs = result.get("processes")
        if procs and result["anchor"].get("available"):
            result["anchor"]["processes_over_anchor"] = procs["samples_per_s"] / result["anchor"]["samples_per_s"]
    return result


def _noise_processes(batch: int, size: int, cfg: TerrainConfig, single: np.ndarray, repeats: int) -> dict:
    """The same heightfields split by samples over one process per core (``sim/parallel.py``)."""
    from ..sim.parallel import ProcessHeightfields

    processes = min(os.cpu_count() or 1, 8)
    with ProcessHeightfields(batch, size, cfg, seed=SEED, processes=processes) as terrains:
        times = _time(terrains.make, "cpu", repeats)
        same = bool(np.array_equal(terrains.make(), single))
    timing = _timing(times)
    return {"processes": processes, **timing, "samples_per_s": batch * size * size / timing["median_s"], "equal_to_one_process": same}


def _noise_anchor(batch: int, size: int, cfg: TerrainConfig, repeats: int, ours_per_s: float) -> dict:
    """FastNoiseLite (pyfastnoiselite) Perlin fBm on the same vertices, in one thread.

    Coordinates are metres (vertex (i, j) of field k at ``x = (i - (size-1)/2) * cell`` plus a
    per-field offset, so the 64 fields are 64 different terrains) and ``frequency = 1 /
    feature_size``: the first octave has the same 16 m wavelength as ours, then ``octaves``
    octaves with the same lacunarity and gain. ``gen_from_coords`` is a single-threaded Cython
    loop; the float32 (2, N) coordinates exist before the clock, as our vertex grid does.
    """
    try:
        from pyfastnoiselite.pyfastnoiselite import FastNoiseLite, FractalType, NoiseType
    except (ImportError, OSError) as err:
        return _unavailable("pyfastnoiselite", err)
    noise = FastNoiseLite(SEED)
    noise.noise_type = NoiseType.NoiseType_Perlin
    noise.fractal_type = FractalType.FractalType_FBm
    noise.fractal_octaves = int(cfg.octaves)
    noise.fractal_lacunarity = float(cfg.lacunarity)
    noise.fractal_gain = float(cfg.persistence)
    noise.frequency = 1.0 / float(cfg.feature_size)
    axis = (np.arange(size) - 0.5 * (size - 1)) * cfg.cell
    x, y = np.meshgrid(axis, axis, indexing="ij")
    k = np.arange(batch)
    spacing = 2.0 * size * cfg.cell  # fields side by side, 8 per row, coordinates stay small
    ox = ((k % 8) * spacing)[:, None, None]
    oy = ((k // 8) * spacing)[:, None, None]
    coords = np.ascontiguousarray(np.stack([(x[None] + ox).ravel(), (y[None] + oy).ravel()]).astype(np.float32))
    samples = int(coords.shape[1])
    out = {}

    def run():
        out["values"] = noise.gen_from_coords(coords)

    timing = _timing(_time(run, "cpu", repeats))
    values = np.asarray(out["values"])
    per_s = samples / timing["median_s"]
    return {
        "available": True, "library": "pyfastnoiselite", "version": _version("pyfastnoiselite"), "threads": 1,
        "noise_type": "Perlin", "fractal_type": "FBm", "octaves": int(cfg.octaves), "lacunarity": float(cfg.lacunarity),
        "gain": float(cfg.persistence), "frequency_per_m": 1.0 / float(cfg.feature_size), "samples": samples,
        "value_range": [float(values.min()), float(values.max())], **timing,
        "samples_per_s": per_s, "ours_over_anchor": ours_per_s / per_s,
    }


def _rays_lidar(columns: int):
    """The RAYS sensor: HDL-64E elevations, ``columns`` azimuths, no range noise, no dropout."""
    return lidar_preset("hdl64e", azimuth_step_deg=360.0 / columns, range_noise_std=0.0, dropout=0.0)


def bench_rays(device=None, quick: bool = False, repeats: int | None = None, anchor: bool = True) -> dict:
    """HDL-64E-like scan (64 rings x 2048 columns) over a 512x512, 0.1 m fBm heightfield; with
    the Open3D ``RaycastingScene`` anchor on the same triangles and rays where it is installed."""
    device = resolve_device(device)
    size, cell = (128, 0.1) if quick else (512, 0.1)
    columns = 256 if quick else 2048
    repeats = repeats or (2 if quick else 5)
    lidar = _rays_lidar(columns)
    terrain = TerrainConfig(name="bench", octaves=5, feature_size=16.0, amplitude=1.5, cell=cell)
    terrain.validate()
    heights = make_heightfields(1, size, terrain, SEED, device)
    wp.synchronize_device(device)
    out = {}

    def run():  # reach 0: rays run to the heightfield's edge, as on the anchor's mesh
        out["points"], out["sensor_z"] = trace(heights, cell, lidar, SEED, device, reach=0.0)

    times = _time(run, device, repeats)
    timing = _timing(times)
    points = out["points"].numpy().reshape(-1, 3)
    hits = float(np.isfinite(points[:, 0]).mean())
    rays = lidar.num_rays
    rays_per_s = rays / timing["median_s"]
    params = {"lidar": lidar.name, "channels": lidar.channels, "columns": lidar.columns, "rays": rays,
              "mount_height_m": lidar.mount_height, "max_range_m": lidar.max_range,
              "size": size, "cell_m": cell, "extent_m": (size - 1) * cell, "octaves": terrain.octaves,
              "feature_size_m": terrain.feature_size, "amplitude_m": terrain.amplitude, "seed": SEED}
    result = _result("rays", device, params, **timing, rays_per_s=rays_per_s, hit_fraction=hits)
    if device == "cpu" and not quick and (os.cpu_count() or 1) > 1:
        result["processes"] = _rays_processes(heights.numpy(), cell, lidar, points, repeats)
    if anchor:
        sensor_z = float(out["sensor_z"].numpy()[0])
        distances = np.linalg.norm(points.astype(np.float64), axis=1)  # sensor frame, no augmentation: |p| = t
        result["anchor"] = _rays_anchor(heights.numpy()[0], cell, lidar, sensor_z, distances, rays_per_s, repeats)
        procs = result.get("processes")
        if procs and result["anchor"].get("available"):
            for run in result["anchor"]["runs"]:
                for kind in ("cast", "fresh"):
                    run[kind]["processes_over_anchor"] = procs["rays_per_s"] / run[kind]["rays_per_s"]
    return result


def _rays_processes(heights: np.ndarray, cell: float, lidar, single: np.ndarray, repeats: int) -> dict:
    """The same scan split by azimuth columns over one process per core (``sim/parallel.py``)."""
    from ..sim.parallel import ProcessTracer

    processes = min(os.cpu_count() or 1, 8)
    with ProcessTracer(heights, cell, lidar, seed=SEED, processes=processes, reach=0.0) as tracer:
        times = _time(tracer.cast, "cpu", repeats)
        same = bool(np.array_equal(tracer.cast().reshape(single.shape), single, equal_nan=True))
    timing = _timing(times)
    return {"processes": processes, **timing, "rays_per_s": lidar.num_rays / timing["median_s"], "equal_to_one_process": same}


def heightfield_triangles(heights: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """The triangle mesh our ray caster intersects: ``(H*W, 3)`` float32 vertices, vertex
    (i, j) at ``((i - (H-1)/2) cell, (j - (W-1)/2) cell, heights[i, j])``, and ``(2 (H-1)(W-1), 3)``
    uint32 triangles, each cell split along its (i, j)-(i+1, j+1) diagonal as in
    ``kernels/heightfield.py``: (i,j)-(i+1,j)-(i+1,j+1) (triangle A) and (i,j)-(i+1,j+1)-(i,j+1) (B).
    """
    heights = np.asarray(heights, dtype=np.float32)
    H, W = heights.shape
    i, j = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    vertices = np.stack([(i - 0.5 * (H - 1)) * cell, (j - 0.5 * (W - 1)) * cell, heights], -1).reshape(-1, 3)
    a, b = np.meshgrid(np.arange(H - 1), np.arange(W - 1), indexing="ij")
    v00, v10, v01, v11 = ((a * W + b).ravel(), ((a + 1) * W + b).ravel(), (a * W + b + 1).ravel(), ((a + 1) * W + b + 1).ravel())
    triangles = np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)])
    return np.ascontiguousarray(vertices, dtype=np.float32), np.ascontiguousarray(triangles, dtype=np.uint32)


def _open3d_rays(directions: np.ndarray, sensor_z: float) -> np.ndarray:
    d = np.asarray(directions, dtype=np.float32)
    origin = np.broadcast_to(np.array([0.0, 0.0, sensor_z], dtype=np.float32), d.shape)
    return np.ascontiguousarray(np.concatenate([origin, d], 1), dtype=np.float32)


def _returns(t: np.ndarray, lidar) -> np.ndarray:
    """Open3D hit distances as our LIDAR reports them: NaN outside ``[min_range, max_range]``."""
    t = np.asarray(t, dtype=np.float64)
    return np.where(np.isfinite(t) & (t >= lidar.min_range) & (t <= lidar.max_range), t, np.nan)


def open3d_hits(heights: np.ndarray, cell: float, lidar, sensor_z: float, nthreads: int = 0) -> np.ndarray:
    """Distances along ``lidar.ray_directions()`` from ``(0, 0, sensor_z)`` to the heightfield's
    mesh (:func:`heightfield_triangles`) by Open3D's ``RaycastingScene``; NaN where our LIDAR
    would report no return (no hit, or outside ``[min_range, max_range]``). Needs open3d."""
    import open3d as o3d

    vertices, triangles = heightfield_triangles(heights, cell)
    scene = o3d.t.geometry.RaycastingScene(nthreads=nthreads)
    scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(triangles))
    t = scene.cast_rays(o3d.core.Tensor(_open3d_rays(lidar.ray_directions(), sensor_z)), nthreads=nthreads)["t_hit"].numpy()
    return _returns(t, lidar)


def compare_hits(ours: np.ndarray, anchor: np.ndarray, tolerance: float = AGREEMENT_TOLERANCE_M) -> dict:
    """Agreement of two per-ray distance arrays (NaN = no return)."""
    ours, anchor = np.asarray(ours, dtype=np.float64), np.asarray(anchor, dtype=np.float64)
    hit_ours, hit_anchor = np.isfinite(ours), np.isfinite(anchor)
    both = hit_ours & hit_anchor
    diff = np.abs(ours[both] - anchor[both])
    within = int((diff <= tolerance).sum())
    return {
        "rays": int(ours.size),
        "both_hit": int(both.sum()),
        "both_hit_within_tolerance": within,
        "within_tolerance_fraction": within / int(both.sum()) if both.any() else math.nan,
        "only_ours_hit": int((hit_ours & ~hit_anchor).sum()),
        "only_anchor_hit": int((hit_anchor & ~hit_ours).sum()),
        "max_abs_diff_m": float(diff.max()) if diff.size else math.nan,
        "tolerance_m": float(tolerance),
        "agree": bool(within == int(both.sum()) and not (hit_ours ^ hit_anchor).any()),
    }


def _rays_anchor(heights: np.ndarray, cell: float, lidar, sensor_z: float, ours: np.ndarray, ours_per_s: float, repeats: int) -> dict:
    """Open3D ``RaycastingScene`` (Embree BVH) on the same mesh and rays.

    Open3D builds its BVH lazily, at the first query after ``add_triangles``: "fresh" times a new
    scene, ``add_triangles`` and the first ``cast_rays`` (what a new terrain costs: our
    caster's equivalent is the whole ``trace``, tile build included); "cast" times
    ``cast_rays`` on the built scene. Each with all threads (``nthreads=0``, Open3D's default)
    and with one (``nthreads=1`` for the scene and the cast). The mesh's vertex and index
    arrays are made before the clock, as our heightfield is.
    """
    try:
        import open3d as o3d
    except (ImportError, OSError) as err:
        return _unavailable("open3d", err)
    vertices, triangles = heightfield_triangles(heights, cell)
    rays = _open3d_rays(lidar.ray_directions(), sensor_z)
    n = rays.shape[0]
    runs = []
    anchor_t = None
    for label, nthreads in (("all", 0), ("1", 1)):
        state = {}

        def fresh(nthreads=nthreads, state=state):
            scene = o3d.t.geometry.RaycastingScene(nthreads=nthreads)
            scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(triangles))
            state["scene"] = scene
            state["t"] = scene.cast_rays(o3d.core.Tensor(rays), nthreads=nthreads)["t_hit"].numpy()

        def cast(nthreads=nthreads, state=state):
            state["t"] = state["scene"].cast_rays(o3d.core.Tensor(rays), nthreads=nthreads)["t_hit"].numpy()

        fresh_timing = _timing(_time(fresh, "cpu", repeats))
        cast_timing = _timing(_time(cast, "cpu", repeats))
        if anchor_t is None:
            anchor_t = state["t"]
        runs.append({
            "threads": label,
            "nthreads_arg": nthreads,
            "fresh": {**fresh_timing, "rays_per_s": n / fresh_timing["median_s"], "ours_over_anchor": ours_per_s / (n / fresh_timing["median_s"])},
            "cast": {**cast_timing, "rays_per_s": n / cast_timing["median_s"], "ours_over_anchor": ours_per_s / (n / cast_timing["median_s"])},
            "build_s": max(fresh_timing["median_s"] - cast_timing["median_s"], 0.0),
        })
    return {
        "available": True, "library": "open3d", "version": _version("open3d"), "cpu_count": os.cpu_count(),
        "triangles": int(triangles.shape[0]), "rays": int(n), "runs": runs,
        "agreement": compare_hits(ours, _returns(anchor_t, lidar)),
    }


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
        stages[name] = float(statistics.median(_time(fn, device, repeats)))
    return stages


def bench_stream(device=None, quick: bool = False, batches: Iterable[int] | None = None, repeats: int | None = None) -> dict:
    """``generate_batch(B, SimConfig())`` for a few batch sizes, with a per-stage breakdown."""
    device = resolve_device(device)
    batches = [int(b) for b in (batches or ((1, 2) if quick else (1, 16)))]
    if any(b < 1 for b in batches):
        raise ValueError(f"batches={batches!r}: every batch size must be >= 1")
    repeats = repeats or (2 if quick else 3)
    sim = SimConfig()
    sim.validate()
    size = terrain_size(sim)
    runs = []
    for batch in batches:
        times = _time(lambda: generate_batch(batch, sim, seed=SEED, device=device), device, repeats)
        timing = _timing(times)
        stages = _stream_stages(batch, sim, device, repeats)
        total = sum(stages.values())
        runs.append({
            "batch": batch,
            **timing,
            "pairs_per_s": batch / timing["median_s"],
            "rays_per_s": batch * sim.lidar.num_rays / timing["median_s"],
            "breakdown_s": stages,
            "breakdown_sum_s": total,
            "breakdown_fraction": {k: (v / total if total > 0 else math.nan) for k, v in stages.items()},
        })
    params = {"batches": batches, "lidar": sim.lidar.name, "rays_per_scan": sim.lidar.num_rays,
              "map_size": sim.data.map_size, "map_cell_m": sim.data.map_cell,
              "terrain": sim.terrain.name, "terrain_size": size, "terrain_cell_m": sim.terrain.cell,
              "octaves": sim.terrain.octaves, "augment": sim.data.augment, "noise": sim.data.noise,
              "truth_samples": sim.data.truth_samples, "clip_rays": bool(getattr(sim.data, "clip_rays", False)), "seed": SEED}
    return _result("stream", device, params, pairs_per_s={str(r["batch"]): r["pairs_per_s"] for r in runs}, runs=runs)


def bench_loader(device=None, quick: bool = False, workers: Iterable[int] = (0, 1, 2), batch: int = 8) -> dict:
    """The training stream (default data, batch 8) as training pulls it: in-process and with
    generator worker processes (CPU only; on CUDA generation stays in-process)."""
    from ..training.config import RunConfig
    from ..data.stream import training_batches

    device = resolve_device(device)
    sim = RunConfig().sim()
    count = 2 if quick else 12
    runs = []
    for n in workers if device == "cpu" else (0,):
        it = training_batches(sim, batch, seed=SEED, rank=0, start=0, stop=count + 1, device=device, workers=int(n), prefetch=4)
        next(it)  # start-up (process spawn, kernel load) excluded
        t = time.perf_counter()
        for _ in range(count):
            next(it)
        dt = time.perf_counter() - t
        runs.append({"workers": int(n), "batches": count, "seconds": dt, "pairs_per_s": batch * count / dt})
        del it
    params = {"batch": batch, "lidar": sim.lidar.name, "map_size": sim.data.map_size, "seed": SEED}
    return _result("loader", device, params, runs=runs, pairs_per_s={str(r["workers"]): r["pairs_per_s"] for r in runs})


# ------------------------------------------------------------------------------- train
def _train_model_config(quick: bool):
    from ..models import ModelConfig

    # the paper's model: Table 2's generator (ngf 64) and the 70x70 PatchGAN; --quick: 8 filters
    return ModelConfig(name="paper", ngf=8, ndf=8) if quick else ModelConfig(name="paper")


def _fixed_pair(batch: int, device: str) -> dict[str, torch.Tensor]:
    """One training batch of the default stream, generated once (its time excluded)."""
    from ..training.config import RunConfig
    from ..data.stream import make_pair

    return make_pair(RunConfig().sim(), batch, SEED & 0x7FFFFFFF, device)


def _build_train_model(model_cfg, device: str, channels_last: bool = False):
    from ..models import build_model

    torch.manual_seed(SEED)
    model = build_model(model_cfg).to(device)
    if channels_last:
        model.netG.to(memory_format=torch.channels_last)
        model.netD.to(memory_format=torch.channels_last)
    model.train()
    return model


def _train_inputs(pair: dict, in_channels: int, device: str, channels_last: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    from ..models.inputs import model_input

    pair = {k: v.to(device) for k, v in pair.items() if k != "step"}
    x, y = model_input(pair["scan"], pair["mask"], in_channels), pair["target"]
    if channels_last:
        x, y = x.contiguous(memory_format=torch.channels_last), y.contiguous(memory_format=torch.channels_last)
    return x, y


def _train_fixed(model_cfg, batch: int, device: str, repeats: int, channels_last: bool = False) -> dict:
    """Optimiser steps (D then G, as training does) on one fixed batch: no data time."""
    model = _build_train_model(model_cfg, device, channels_last)
    x, y = _train_inputs(_fixed_pair(batch, device), model_cfg.in_channels, device, channels_last)

    def step():
        model.set_input(x, y)
        model.optimize_parameters()

    timing = _timing(_time(step, device, repeats))
    return {**timing, "images_per_s": batch / timing["median_s"]}


def _train_stream(model_cfg, batch: int, device: str, steps: int) -> dict:
    """The same steps pulling their batches from the training stream (``workers=0``: generated
    in this process, as on CUDA): ``data_wait_share`` = time in ``next(batches)`` / step time."""
    from ..training.config import RunConfig
    from ..models.inputs import model_input
    from ..data.stream import training_batches

    model = _build_train_model(model_cfg, device)
    batches = training_batches(RunConfig().sim(), batch, SEED, 0, 0, steps + 1, device, 0)

    def step() -> tuple[float, float]:
        _sync(device)
        t0 = time.perf_counter()
        pair = next(batches)
        t1 = time.perf_counter()
        pair = {k: v.to(device, non_blocking=True) for k, v in pair.items() if k != "step"}
        model.set_input(model_input(pair["scan"], pair["mask"], model_cfg.in_channels), pair["target"])
        model.optimize_parameters()
        _sync(device)
        return t1 - t0, time.perf_counter() - t0

    step()  # warm-up (kernel loading, first allocations)
    waits, totals = zip(*(step() for _ in range(steps)))
    total = sum(totals)
    return {
        "steps": steps, "workers": 0, "seconds": total, "step_times_s": [float(t) for t in totals],
        "data_wait_s": [float(t) for t in waits], "images_per_s": batch * steps / total,
        "data_wait_share": sum(waits) / total,
    }


def _compiled_child(spec_json: str) -> None:
    """Runs in a fresh interpreter (see :func:`_train_compiled`): the fixed-batch steps with
    ``torch.compile``'d nets; prints one JSON line when compiled and one when done."""
    import warp_terrain  # noqa: F401  (Warp's log level)
    from ..models import ModelConfig

    spec = json.loads(spec_json)
    device, batch, repeats = spec["device"], int(spec["batch"]), int(spec["repeats"])
    torch.set_num_threads(int(spec["threads"]))
    model_cfg = ModelConfig(**spec["model"])
    model = _build_train_model(model_cfg, device)
    model.netG = torch.compile(model.netG)
    model.netD = torch.compile(model.netD)
    x, y = _train_inputs(_fixed_pair(batch, device), model_cfg.in_channels, device)

    def step():
        model.set_input(x, y)
        model.optimize_parameters()

    print(json.dumps({"event": "ready"}), flush=True)
    t0 = time.perf_counter()
    step()  # compiles G's forward and backward and D's two variants (D trained, then frozen)
    step()  # anything compiled late (e.g. guards on the second call)
    _sync(device)
    print(json.dumps({"event": "compiled", "first_two_steps_s": time.perf_counter() - t0}), flush=True)
    print(json.dumps({"event": "done", **_timing(_time(step, device, repeats, warmup=0))}), flush=True)


def _train_compiled(model_cfg, batch: int, device: str, repeats: int, plain_step_s: float, threads: int,
                    limit_s: float = COMPILE_LIMIT_S) -> dict:
    """``torch.compile`` (inductor) variant, in a child process so that a compile that fails
    or takes longer than ``limit_s`` is recorded, not fatal: after its start-up (imports, model,
    data: up to 120 s more) the child gets ``limit_s`` for compilation and its first two steps,
    then generous time for ``repeats`` timed steps; past a deadline it is killed. Inductor gets
    an empty cache folder, so the compile is cold (what a first run pays) and reproducible."""
    with tempfile.TemporaryDirectory(prefix="warp-terrain-inductor-") as cache:
        result = _run_compiled_child(model_cfg, batch, device, repeats, plain_step_s, threads, limit_s, cache)
    return {**result, "inductor_cache": "empty (cold compile)"}


def _run_compiled_child(model_cfg, batch: int, device: str, repeats: int, plain_step_s: float, threads: int,
                        limit_s: float, cache: str) -> dict:
    spec = json.dumps({"device": device, "batch": batch, "repeats": repeats, "threads": threads, "model": model_cfg.to_dict()})
    code = "import sys; from warp_terrain.bench import _compiled_child; _compiled_child(sys.argv[1])"
    env = {**os.environ, "TORCHINDUCTOR_CACHE_DIR": cache}
    t_start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", code, spec], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env, start_new_session=True)  # its own group: inductor's compile workers go with it
    lines: queue.Queue = queue.Queue()
    err_tail: list[str] = []

    def pump_stdout():
        for line in proc.stdout:
            lines.put(line)
        lines.put(None)  # end of output: the child exited

    def pump_stderr():
        for line in proc.stderr:
            err_tail.append(line)
            del err_tail[:-20]

    threading.Thread(target=pump_stdout, daemon=True).start()
    threading.Thread(target=pump_stderr, daemon=True).start()

    def kill() -> None:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        proc.wait()

    deadline = t_start + 120.0 + limit_s  # start-up, until "ready"
    phase_start, phase = t_start, "start-up"
    compiled = None
    while True:
        try:
            line = lines.get(timeout=max(deadline - time.perf_counter(), 0.0))
        except queue.Empty:
            kill()
            return {"available": False, "limit_s": limit_s,
                    "reason": f"torch.compile: {phase} took more than {deadline - phase_start:.0f} s (killed)"}
        if line is None:  # the child ended without reporting
            kill()
            tail = " | ".join(x.strip() for x in err_tail[-3:] if x.strip())
            return {"available": False, "reason": f"torch.compile failed (exit {proc.returncode}): {tail[-400:]}", "limit_s": limit_s}
        try:
            event = json.loads(line)
        except json.JSONDecodeError:
            continue
        if event.get("event") == "ready":
            phase_start, phase = time.perf_counter(), "compilation (first two steps)"
            deadline = phase_start + limit_s
        elif event.get("event") == "compiled":
            compiled = event
            phase_start, phase = time.perf_counter(), "the timed steps"
            deadline = phase_start + 60.0 + 5.0 * repeats * plain_step_s
        elif event.get("event") == "done":
            kill()  # the child is done; also any stragglers of its group (inductor's compile workers)
            event.pop("event")
            first = compiled["first_two_steps_s"]
            return {"available": True, **event, "images_per_s": batch / event["median_s"],
                    "first_two_steps_s": first, "compile_s": max(first - 2.0 * event["median_s"], 0.0),
                    "limit_s": limit_s}


def _train_threads(device: str) -> int:
    """torch threads as training uses them by default: on the CPU, the cores the default
    generator worker process leaves (``train.threads=0``, ``train.workers=1``)."""
    from ..training.config import TrainConfig

    if not device.startswith("cpu"):
        return torch.get_num_threads()
    return max(1, (os.cpu_count() or 1) - TrainConfig().workers)


def bench_train(device=None, quick: bool = False, batches: Iterable[int] | None = None, repeats: int | None = None,
                compile: bool | None = None, threads: int | None = None) -> dict:
    """The paper's model (Table 2 generator, ngf 64, and the PatchGAN): images/s of pix2pix
    optimiser steps for batch 1 (the paper's) and 8.

    Per batch size, with ``threads`` torch threads (default: as training sets them, see
    :func:`_train_threads`): ``plain`` (fixed batch, no data time), ``channels_last`` (nets and
    inputs in channels-last memory format), ``stream`` (batches pulled from the training stream
    in this process, ``workers=0``, with the share of step time spent waiting for data). For the
    first batch size also ``plain_all_threads`` (plain with torch's own thread count, if it
    differs) and ``compile`` (``torch.compile`` of both nets in a child process; compile time
    excluded from images/s but reported; a failure or a compile over ``COMPILE_LIMIT_S`` is
    recorded with its reason). ``quick``: 8 filters, batch 1, one step each, no compile and no
    all-threads repeat.
    """
    device = resolve_device(device)
    model_cfg = _train_model_config(quick)
    batches = [int(b) for b in (batches or ((1,) if quick else (1, 8)))]
    if any(b < 1 for b in batches):
        raise ValueError(f"batches={batches!r}: every batch size must be >= 1")
    repeats = repeats or (1 if quick else 3)
    compile = (not quick) if compile is None else bool(compile)
    all_threads = torch.get_num_threads()
    threads = int(threads or _train_threads(device))
    runs = []
    for k, batch in enumerate(batches):
        with _torch_threads(threads):
            plain = _train_fixed(model_cfg, batch, device, repeats)
            channels_last = _train_fixed(model_cfg, batch, device, repeats, channels_last=True)
            stream = _train_stream(model_cfg, batch, device, repeats)
        channels_last["over_plain"] = channels_last["images_per_s"] / plain["images_per_s"]
        stream["over_plain"] = stream["images_per_s"] / plain["images_per_s"]
        run = {"batch": batch, "threads": threads, "plain": plain, "channels_last": channels_last, "stream": stream}
        if k == 0:
            if all_threads != threads and not quick:
                with _torch_threads(all_threads):
                    other = _train_fixed(model_cfg, batch, device, repeats)
                run["plain_all_threads"] = {"threads": all_threads, **other, "over_plain": other["images_per_s"] / plain["images_per_s"]}
            if compile:
                compiled = _train_compiled(model_cfg, batch, device, repeats, plain["median_s"], threads)
                if compiled["available"]:
                    compiled["over_plain"] = compiled["images_per_s"] / plain["images_per_s"]
            else:
                compiled = {"available": False, "reason": "skipped (--quick)" if quick else "skipped"}
            run["compile"] = compiled
        runs.append(run)
    params = {"model": model_cfg.name, "ngf": model_cfg.ngf, "ndf": model_cfg.ndf, "norm": model_cfg.norm,
              "gan_mode": model_cfg.gan_mode, "batches": batches, "repeats": repeats, "map_size": 121,
              "torch_threads": threads, "torch_threads_default": all_threads, "compile_limit_s": COMPILE_LIMIT_S, "seed": SEED}
    return _result("train", device, params, runs=runs,
                   images_per_s={str(r["batch"]): r["plain"]["images_per_s"] for r in runs},
                   data_wait_share={str(r["batch"]): r["stream"]["data_wait_share"] for r in runs})


# ------------------------------------------------------------------------------- infer
def _onnx_session(generator: torch.nn.Module, in_channels: int, map_size: int, threads_list: list[int]) -> tuple[dict, dict]:
    """Export ``generator`` to a temporary ONNX file and open one ONNX Runtime CPU session per
    thread count; ``({threads: session}, info)`` or ``({}, why not)``."""
    try:
        import onnxruntime as ort

        from ..inference.onnx import export_onnx
    except (ImportError, OSError) as err:
        return {}, _unavailable("onnxruntime", err)
    try:
        sessions = {}
        with tempfile.TemporaryDirectory() as tmp:
            path = export_onnx(copy.deepcopy(generator).cpu(), os.path.join(tmp, "generator.onnx"), in_channels, map_size)
            for n in threads_list:
                options = ort.SessionOptions()
                options.intra_op_num_threads = int(n)
                options.inter_op_num_threads = 1
                sessions[n] = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    except Exception as err:  # noqa: BLE001  (an exporter or runtime problem is a finding, not a crash)
        return {}, {"available": False, "reason": f"export or load failed ({type(err).__name__}: {' '.join(str(err).split())[:300]})"}
    return sessions, {"available": True, "version": _version("onnxruntime"), "provider": "CPUExecutionProvider"}


def bench_infer(device=None, quick: bool = False, repeats: int | None = None) -> dict:
    """Points -> map latency of the shipped ``Reconstructor`` on HDL-32E scans, and its network
    under torch and ONNX Runtime (CPU provider) with their max abs difference.

    ``end_to_end``: batch 1 is ``reconstruct(points)`` on one scan (its returns only: the NaN
    rows of no-return rays dropped before the clock); batch 4 is ``project_points`` of 4 scans
    at once plus one ``predict_maps`` call (both with the Reconstructor's default test-time
    augmentation: 8 network passes per map). ``network``: the generator alone on the conditions
    of those scans, torch (no grad) and ONNX Runtime (exported with ``export_onnx``). Each run
    once with torch's thread count (ONNX Runtime's intra-op threads the same) and, if that is
    more than one, once with one thread (``quick``: one thread only).
    """
    from ..inference.reconstructor import Reconstructor
    from ..sim.projection import project_points

    device = resolve_device(device)
    repeats = repeats or (2 if quick else 10)
    batches = (1, 4)
    rec = Reconstructor.load(device=device)
    sim = SimConfig()
    sim.validate()
    scans = generate_batch(max(batches), sim, seed=SEED, device=device).points
    cloud = scans[0].cpu().numpy()
    cloud = cloud[np.isfinite(cloud).all(axis=1)]
    size, cell = sim.data.map_size, sim.data.map_cell
    scan, mask = project_points(scans, map_size=size, map_cell=cell, device=device)
    condition = rec.condition(scan, mask)
    # --quick: one thread only (torch's OpenMP threads slow down many times over when another
    # process holds a core, which would make the smoke test slow and erratic on shared machines)
    threads_list = [1] if quick else list(dict.fromkeys([torch.get_num_threads(), 1]))
    sessions, onnx = _onnx_session(rec.generator, rec.model_config.in_channels, size, threads_list)
    out = {}
    runs = []
    for threads in threads_list:
        end_to_end, network = {}, {}
        with _torch_threads(threads):
            for batch in batches:
                if batch == 1:
                    fn = lambda: rec.reconstruct(cloud, size, cell)  # noqa: E731
                else:
                    def fn(points=scans[:batch]):
                        scan, mask = project_points(points, map_size=size, map_cell=cell, device=device)
                        return rec.predict_maps(scan, mask).cpu()
                timing = _timing(_time(fn, device, repeats))
                end_to_end[str(batch)] = {**timing, "median_ms": timing["median_s"] * 1e3, "maps_per_s": batch / timing["median_s"]}

                def run(x=condition[:batch]):
                    with torch.no_grad():
                        out["torch"] = rec.generator(x)

                timing = _timing(_time(run, device, repeats))
                network[str(batch)] = {"torch": {**timing, "median_ms": timing["median_s"] * 1e3}}
        if threads in sessions:
            for batch in batches:
                x = condition[:batch].float().cpu().numpy()

                def run(x=x, session=sessions[threads]):
                    out["onnx"] = session.run(["height"], {"condition": x})[0]

                timing = _timing(_time(run, "cpu", repeats))
                with torch.no_grad():
                    expected = rec.generator(condition[:batch])[:, :1].float().cpu().numpy()  # the height channel
                entry = network[str(batch)]
                entry["onnxruntime"] = {**timing, "median_ms": timing["median_s"] * 1e3,
                                        "speedup_over_torch": entry["torch"]["median_s"] / timing["median_s"]}
                entry["max_abs_diff_m"] = float(np.abs(expected - out["onnx"]).max())
        runs.append({"threads": threads, "end_to_end": end_to_end, "network": network})
    params = {"model": rec.model_config.name, "ngf": rec.model_config.ngf, "in_channels": rec.model_config.in_channels,
              "residual": rec.model_config.residual, "tta": rec.tta, "lidar": sim.lidar.name, "points_in_cloud": int(cloud.shape[0]),
              "rays_per_scan": sim.lidar.num_rays, "map_size": size, "map_cell_m": cell, "batches": list(batches),
              "threads": threads_list, "seed": SEED}
    return _result("infer", device, params, runs=runs, onnxruntime=onnx,
                   latency_ms={str(r["threads"]): {k: v["median_ms"] for k, v in r["end_to_end"].items()} for r in runs})


BENCHMARKS: dict[str, Callable[..., dict]] = {
    "noise": bench_noise,
    "rays": bench_rays,
    "stream": bench_stream,
    "loader": bench_loader,
    "train": bench_train,
    "infer": bench_infer,
}


def parse_only(only) -> list[str]:
    """Benchmark names from None (all), ``"noise,rays"`` or an iterable of names."""
    if only is None:
        return list(BENCHMARKS)
    names = [s.strip() for s in only.split(",")] if isinstance(only, str) else [str(s).strip() for s in only]
    names = [n for n in names if n]
    unknown = [n for n in names if n not in BENCHMARKS]
    if unknown or not names:
        raise ValueError(f"only={only!r}: unknown or no benchmark names; choose from {', '.join(BENCHMARKS)}")
    return list(dict.fromkeys(names))


def run_benchmarks(device=None, only=None, quick: bool = False, progress: Callable[[str], None] | None = None) -> dict:
    """Run the selected benchmarks (all by default) on ``device``; a JSON-ready dict.

    ``only``: None, ``"noise,rays,stream"`` or a list of those names. ``quick``: tiny workloads
    and fewer repeats (a smoke test, not a measurement). ``progress`` receives one line per step.
    """
    names = parse_only(only)
    device = resolve_device(device)
    results = {}
    for name in names:
        if progress:
            progress(f"bench {name} on {device}{' (quick)' if quick else ''} ...")
        t0 = time.perf_counter()
        results[name] = BENCHMARKS[name](device=device, quick=quick)
        if progress:
            progress(f"bench {name} done in {time.perf_counter() - t0:.1f} s")
    return {"environment": environment(device), "quick": bool(quick), "results": results}


# ------------------------------------------------------------------------------- table
def _rate(x: float) -> str:
    for scale, unit in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if x >= scale:
            return f"{x / scale:.2f}{unit} "
    return f"{x:.2f} "


def _ms(seconds: float) -> str:
    return f"{seconds * 1e3:.2f} ms" if seconds < 10 else f"{seconds:.2f} s"


def _x(ratio: float) -> str:
    return f"{ratio:.2f}x" if ratio < 10 else f"{ratio:.1f}x"


def _processes_row(name: str, procs: dict, what: str, unit: str, single_per_s: float) -> tuple[str, str, str, str]:
    """The table row of a workload split over processes (``sim/parallel.py``)."""
    per_s = procs[f"{unit}_per_s"]
    n = procs["processes"]
    return (f"{name} {n} proc", f"{what} over {n} processes (sim/parallel.py); equal to 1 process: {'yes' if procs['equal_to_one_process'] else 'NO'}",
            _ms(procs["median_s"]), f"{_rate(per_s)}{unit}/s ({per_s / single_per_s:.2f}x 1 process)")


def _processes_over(procs: dict | None, anchor_timing: dict) -> str:
    """``", N proc = R"``: the process split's ratio to an anchor timing, when there is one."""
    if not procs or "processes_over_anchor" not in anchor_timing:
        return ""
    return f", {procs['processes']} proc = {_x(anchor_timing['processes_over_anchor'])}"


def format_table(report: dict) -> str:
    """A readable table of :func:`run_benchmarks`' result; "ours = N x anchor" compares our
    throughput with the anchor's on the same workload (> 1: ours is faster)."""
    env = report["environment"]
    lines = [
        f"warp-terrain {env['warp_terrain']} bench on {env['device']} ({env['device_name']}, {env['cpu_count']} CPUs)"
        f"  warp {env['warp']}  torch {env['torch']}{'  [quick]' if report.get('quick') else ''}",
        "",
    ]
    rows = [("workload", "parameters", "median", "throughput")]
    res = report["results"]

    def missing(name: str, anchor: dict) -> None:
        rows.append((name, anchor.get("reason", "not available"), "", ""))

    if "noise" in res:
        r, p = res["noise"], res["noise"]["params"]
        rows.append(("noise", f"{p['batch']} fBm heightfields {p['size']}x{p['size']}, {p['octaves']} octaves",
                     _ms(r["median_s"]), f"{_rate(r['samples_per_s'])}samples/s ({r['heightfields_per_s']:.0f} fields/s)"))
        procs = r.get("processes")
        if procs:
            rows.append(_processes_row("noise", procs, "the same fields, samples split", "samples", r["samples_per_s"]))
        a = r.get("anchor")
        if a and a["available"]:
            with_procs = _processes_over(procs, a)
            rows.append(("  anchor", f"pyfastnoiselite {a['version']} Perlin FBm, {a['octaves']} octaves, 1 thread, {a['samples']:,} samples",
                         _ms(a["median_s"]), f"{_rate(a['samples_per_s'])}samples/s; ours = {_x(a['ours_over_anchor'])} anchor{with_procs}"))
        elif a:
            missing("  anchor", a)
    if "rays" in res:
        r, p = res["rays"], res["rays"]["params"]
        rows.append(("rays", f"{p['rays']:,} rays ({p['lidar']} {p['channels']}x{p['columns']}), {p['size']}x{p['size']} @ {p['cell_m']:g} m",
                     _ms(r["median_s"]), f"{_rate(r['rays_per_s'])}rays/s (hits {100 * r['hit_fraction']:.1f}%)"))
        procs = r.get("processes")
        if procs:
            rows.append(_processes_row("rays", procs, "the same scan, columns interleaved", "rays", r["rays_per_s"]))
        a = r.get("anchor")
        if a and a["available"]:
            for run in a["runs"]:
                threads = f"{a['cpu_count']} threads" if run["threads"] == "all" else "1 thread"
                for kind, what in (("cast", "cast only (BVH built)"), ("fresh", "fresh: BVH build + cast")):
                    t = run[kind]
                    with_procs = _processes_over(procs, t)
                    rows.append(("  anchor", f"open3d {a['version']} RaycastingScene, {what}, {threads}",
                                 _ms(t["median_s"]), f"{_rate(t['rays_per_s'])}rays/s; ours = {_x(t['ours_over_anchor'])} anchor{with_procs}"))
            g = a["agreement"]
            rows.append(("  agreement", f"|t_ours - t_open3d| <= {1e3 * g['tolerance_m']:g} mm on {g['both_hit_within_tolerance']:,}"
                                        f" of {g['both_hit']:,} rays both hit; one-sided hits {g['only_ours_hit']} ours, {g['only_anchor_hit']} open3d",
                         "", f"max |dt| {1e3 * g['max_abs_diff_m']:.3f} mm: {'AGREE' if g['agree'] else 'DISAGREE'}"))
        elif a:
            missing("  anchor", a)
    if "stream" in res:
        r, p = res["stream"], res["stream"]["params"]
        for run in r["runs"]:
            rows.append((f"stream B={run['batch']}",
                         f"generate_batch: {p['lidar']} {p['rays_per_scan']:,} rays, terrain {p['terrain_size']}^2, maps {p['map_size']}^2",
                         _ms(run["median_s"]), f"{_rate(run['pairs_per_s'])}pairs/s"))
            b, f = run["breakdown_s"], run["breakdown_fraction"]
            rows.append(("", "  terrain / ray cast / projection+truth",
                         " / ".join(_ms(b[k]) for k in ("terrain", "ray_cast", "projection_truth")),
                         " / ".join(f"{100 * f[k]:.0f}%" for k in ("terrain", "ray_cast", "projection_truth"))))
    if "loader" in res:
        r, p = res["loader"], res["loader"]["params"]
        for run in r["runs"]:
            rows.append((f"loader w={run['workers']}", f"training stream, {p['lidar']}, batch {p['batch']}, {run['workers']} worker processes",
                         _ms(run["seconds"] / run["batches"]), f"{_rate(run['pairs_per_s'])}pairs/s"))
    if "train" in res:
        r, p = res["train"], res["train"]["params"]
        for run in r["runs"]:
            b, t = run["batch"], run["threads"]
            rows.append((f"train B={b}", f"{p['model']} model (ngf {p['ngf']}, ndf {p['ndf']}), steps on a fixed batch, {t} torch thread(s)",
                         _ms(run["plain"]["median_s"]) + "/step", f"{run['plain']['images_per_s']:.2f} images/s"))
            if "plain_all_threads" in run:
                c = run["plain_all_threads"]
                rows.append(("", f"  the same with {c['threads']} torch threads", _ms(c["median_s"]) + "/step",
                             f"{c['images_per_s']:.2f} images/s ({_x(c['over_plain'])} plain)"))
            c = run["channels_last"]
            rows.append(("", "  channels_last", _ms(c["median_s"]) + "/step", f"{c['images_per_s']:.2f} images/s ({_x(c['over_plain'])} plain)"))
            if "compile" in run:
                c = run["compile"]
                if c["available"]:
                    rows.append(("", f"  torch.compile (compile {c['compile_s']:.0f} s, excluded)", _ms(c["median_s"]) + "/step",
                                 f"{c['images_per_s']:.2f} images/s ({_x(c['over_plain'])} plain)"))
                else:
                    rows.append(("", f"  torch.compile: {c['reason']}", "", ""))
            st = run["stream"]
            rows.append(("", f"  + training stream ({st['workers']} workers): data wait {100 * st['data_wait_share']:.0f}% of step time",
                         _ms(st["seconds"] / st["steps"]) + "/step", f"{st['images_per_s']:.2f} images/s ({_x(st['over_plain'])} plain)"))
    if "infer" in res:
        r, p = res["infer"], res["infer"]["params"]
        for run in r["runs"]:
            for batch, e in run["end_to_end"].items():
                what = f"reconstruct(points): {p['points_in_cloud']:,} points" if batch == "1" else f"project {batch} scans + predict_maps"
                rows.append((f"infer B={batch}", f"{what} -> {p['map_size']}^2 map ({p['model']} ngf {p['ngf']}"
                                                 f"{', residual' if p['residual'] else ''}{', 8-orientation TTA' if p.get('tta') else ''}), "
                                                 f"{run['threads']} thread(s)",
                             _ms(e["median_s"]), f"{e['maps_per_s']:.1f} maps/s"))
                n = run["network"][batch]
                rows.append(("", "  network: torch", _ms(n["torch"]["median_s"]), ""))
                if "onnxruntime" in n:
                    o = n["onnxruntime"]
                    rows.append(("", f"  network: onnxruntime {r['onnxruntime']['version']} (max |diff| {n['max_abs_diff_m']:.1e} m)",
                                 _ms(o["median_s"]), f"{_x(o['speedup_over_torch'])} torch"))
        if not r["onnxruntime"]["available"]:
            missing("  onnxruntime", r["onnxruntime"])
    widths = [max(len(row[i]) for row in rows) for i in range(4)]
    for k, row in enumerate(rows):
        lines.append("  ".join(cell.ljust(w) if i < 3 else cell for i, (cell, w) in enumerate(zip(row, widths))).rstrip())
        if k == 0:
            lines.append("  ".join("-" * w for w in widths))
    lines.append("")
    lines.append("median of repeats after one warm-up call (compilation excluded); device synchronised before each clock read")
    lines.append("ours = N x anchor: our throughput over the anchor's on the same work (> 1: ours is faster)")
    return "\n".join(lines)
