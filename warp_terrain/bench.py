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

from . import __version__
from .sim import SimConfig, TerrainConfig, generate_batch, lidar_preset, resolve_device
from .sim.batch import make_maps, make_terrains, scan_terrains, terrain_size
from .sim.scan import trace
from .sim.terrain import make_heightfields

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


def _time(fn: Callable[[], object], device: str, repeats: int) -> list[float]:
    """Seconds per call of ``fn`` over ``repeats`` calls, after one untimed warm-up call."""
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
def bench_noise(device=None, quick: bool = False, repeats: int | None = None) -> dict:
    """fBm heightfields: 64 terrains of 121x121 vertices, 5 octaves, no obstacles."""
    device = resolve_device(device)
    batch, size = (8, 33) if quick else (64, 121)
    repeats = repeats or (2 if quick else 5)
    cfg = TerrainConfig(name="bench", octaves=5, feature_size=16.0, amplitude=1.5, cell=0.25)
    cfg.validate()

    def run():
        return make_heightfields(batch, size, cfg, SEED, device)

    times = _time(run, device, repeats)
    timing = _timing(times)
    params = {"batch": batch, "size": size, "cell_m": cfg.cell, "octaves": cfg.octaves,
              "feature_size_m": cfg.feature_size, "amplitude_m": cfg.amplitude, "seed": SEED}
    return _result(
        "noise", device, params, **timing,
        heightfields_per_s=batch / timing["median_s"],
        samples_per_s=batch * size * size / timing["median_s"],  # fBm values (vertices), as the anchors count them
    )


def bench_rays(device=None, quick: bool = False, repeats: int | None = None) -> dict:
    """HDL-64E-like scan (64 rings x 2048 columns) over a 512x512, 0.1 m fBm heightfield."""
    device = resolve_device(device)
    size, cell = (128, 0.1) if quick else (512, 0.1)
    columns = 256 if quick else 2048
    repeats = repeats or (2 if quick else 5)
    lidar = lidar_preset("hdl64e", azimuth_step_deg=360.0 / columns, range_noise_std=0.0, dropout=0.0)
    terrain = TerrainConfig(name="bench", octaves=5, feature_size=16.0, amplitude=1.5, cell=cell)
    terrain.validate()
    heights = make_heightfields(1, size, terrain, SEED, device)
    wp.synchronize_device(device)
    out = {}

    def run():
        out["points"], _ = trace(heights, cell, lidar, SEED, device)

    times = _time(run, device, repeats)
    timing = _timing(times)
    points = out["points"].numpy().reshape(-1, 3)
    hits = float(np.isfinite(points[:, 0]).mean())
    rays = lidar.num_rays
    params = {"lidar": lidar.name, "channels": lidar.channels, "columns": lidar.columns, "rays": rays,
              "mount_height_m": lidar.mount_height, "max_range_m": lidar.max_range,
              "size": size, "cell_m": cell, "extent_m": (size - 1) * cell, "octaves": terrain.octaves,
              "feature_size_m": terrain.feature_size, "amplitude_m": terrain.amplitude, "seed": SEED}
    return _result("rays", device, params, **timing, rays_per_s=rays / timing["median_s"], hit_fraction=hits)


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
    from .config import RunConfig
    from .training.stream import training_batches

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


BENCHMARKS: dict[str, Callable[..., dict]] = {
    "noise": bench_noise,
    "rays": bench_rays,
    "stream": bench_stream,
    "loader": bench_loader,
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


def format_table(report: dict) -> str:
    """A readable table of :func:`run_benchmarks`' result."""
    env = report["environment"]
    lines = [
        f"warp-terrain {env['warp_terrain']} bench on {env['device']} ({env['device_name']}, {env['cpu_count']} CPUs)"
        f"  warp {env['warp']}  torch {env['torch']}{'  [quick]' if report.get('quick') else ''}",
        "",
    ]
    rows = [("workload", "parameters", "median", "throughput")]
    res = report["results"]
    if "noise" in res:
        r, p = res["noise"], res["noise"]["params"]
        rows.append(("noise", f"{p['batch']} fBm heightfields {p['size']}x{p['size']}, {p['octaves']} octaves",
                     _ms(r["median_s"]), f"{_rate(r['samples_per_s'])}samples/s ({r['heightfields_per_s']:.0f} fields/s)"))
    if "rays" in res:
        r, p = res["rays"], res["rays"]["params"]
        rows.append(("rays", f"{p['rays']:,} rays ({p['lidar']} {p['channels']}x{p['columns']}), {p['size']}x{p['size']} @ {p['cell_m']:g} m",
                     _ms(r["median_s"]), f"{_rate(r['rays_per_s'])}rays/s (hits {100 * r['hit_fraction']:.1f}%)"))
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
    widths = [max(len(row[i]) for row in rows) for i in range(4)]
    for k, row in enumerate(rows):
        lines.append("  ".join(cell.ljust(w) if i < 3 else cell for i, (cell, w) in enumerate(zip(row, widths))).rstrip())
        if k == 0:
            lines.append("  ".join("-" * w for w in widths))
    lines.append("")
    lines.append("median of repeats after one warm-up call (compilation excluded); device synchronised before each clock read")
    return "\n".join(lines)
