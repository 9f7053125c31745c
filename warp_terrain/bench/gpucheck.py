"""GPU-CHECK: one prepared check of a machine, CPU and CUDA, under a hard time limit.

``warp-terrain gpu-check [--quick] [--json OUT]`` (``cli/gpucheck.py``) runs :class:`GpuCheck`:

1. the environment: Python, torch, Warp, the devices, CUDA driver and toolkit, GPU name and memory;
2. ``compile``: every Warp module of ``warp_terrain.kernels`` loaded (compiled, or read from
   Warp's kernel cache) on each device, timed per module;
3. consistency, per device, on two settings (``octave5``, the default; ``wide`` with image noise:
   tilt, relief, landforms, every obstacle kind and clutter, so the per-ray walk):
   ``repeat`` (two runs bit-identical), ``poison`` (a run after freed memory was filled with NaN
   is bit-identical to one before), ``walks`` (the column walk against the per-ray walk on the
   same terrains), ``cuda_vs_cpu`` (terrain to 1e-5 m, >= 99.99 % of rays the same: both miss,
   or both hit within 1 mm; maps: masks, scans and targets), and ``process_split`` on the CPU
   (``sim/parallel.py``: a batch of terrains split across processes equals one process's; with
   the full check also a scan split by azimuth columns); ``capture`` (``BatchGraph``'s replays,
   a CUDA graph on CUDA, bit-identical to ``generate_batch``: a capture fails on any host sync,
   so on CUDA this also shows the batch's launches sync-free) and ``no_sync`` (CUDA: a training
   step under ``torch.cuda.set_sync_debug_mode("error")``);
4. throughput: ``stream b=N`` (``generate_batch`` -> pairs/s, its ray-cast stage -> scans/s,
   and the per-stage times) and ``train b=N`` (optimiser steps of the default model on a fixed
   batch -> training pairs/s; on CUDA also under bf16 autocast and with cuDNN benchmark), timed
   after a warm-up with CUDA events on CUDA (Warp launched on torch's stream) and
   ``perf_counter`` on the CPU; ``stream`` also times ``BatchGraph``'s replays and, on CUDA,
   each kernel (Warp's activity timing);
5. ``switches b=N``: each kernel switch (``sim/switches.py``: compile-time tile, deferred
   writes, the other fBm path) against the default on the same terrains: bit-identical points
   (heights to 1e-5 m for the fBm), and each one's speed-up, so a GPU run shows which to pick.

Each check is one row: PASS, FAIL (with the reason; a check that raises is a FAIL with the
error and its traceback in the JSON) or SKIP (CUDA rows without a CUDA device, with why).
Throughput rows PASS when measured; the issue's targets on an H100/H200 (>= 10,000 pairs/s
at batch >= 64, >= 2,000 training pairs/s) are reported beside them, not enforced.
``quick``: small batches and few repeats (the CI test runs it on the CPU; CUDA rows are
SKIP there). The time limit is cooperative (no check starts, and no timing loop goes on, past
the deadline less a reserve) and hard when :meth:`GpuCheck.run` is given ``on_timeout``: at
the deadline it is called with the report so far (the running check FAIL, those not run SKIP,
a ``time_limit`` row FAIL), and the CLI writes that and exits.
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import json
import math
import os
import pkgutil
import platform
import shutil
import statistics
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np
import torch
import warp as wp

from .. import kernels as kernel_package
from ..core.atomic import atomic_open
from ..core.version import __version__
from ..sim import SimConfig, generate_batch, resolve_device
from ..sim.batch import make_maps, make_terrains, scan_terrains, terrain_size
from ..sim.graph import BatchGraph
from ..sim.parallel import ProcessHeightfields, ProcessTracer
from ..sim.presets import terrain_preset
from ..sim.scan import trace
from ..sim.switches import KernelSwitches, use_kernel_switches
from ..sim.terrain import make_heightfields
from ..training.config import RunConfig
from .harness import SEED, environment, sync_device
from .train import build_train_model, fixed_pair, train_inputs

PASS, FAIL, SKIP = "PASS", "FAIL", "SKIP"
TIME_LIMIT_S = 420.0
#: the check groups, in the order they run (``only`` picks among them)
GROUPS = ("compile", "repeat", "poison", "walks", "cuda_vs_cpu", "capture", "no_sync", "stream", "switches", "train", "process_split")

# consistency criteria (CUDA against the CPU; the column walk against the per-ray walk)
TERRAIN_ATOL_M = 1e-5  # terrain heights and sensor heights
POINT_ATOL_M = 1e-3  # a hit "the same" on both: within 1 mm on each axis
RAY_AGREEMENT_MIN = 0.9999  # share of rays that both miss, or both hit within POINT_ATOL_M
MASK_AGREEMENT_MIN = 0.999  # share of map cells observed on both or on neither
SCAN_AGREEMENT_MIN = 0.999  # share of cells observed on both whose scan heights agree to POINT_ATOL_M
TARGET_ATOL_M = 1e-3  # ground-truth maps (target, target_visible)
# the throughput targets on one H100/H200 (reported, not enforced)
TARGET_PAIRS_PER_S = 10_000.0  # HDL-32E scans with maps (pairs) per second at batch >= 64
TARGET_TRAIN_PAIRS_PER_S = 2_000.0  # training pairs per second, default model
RESERVE_S = 5.0  # the cooperative deadline is this much before the hard one
MIN_START_S = 1.0  # a check does not start with less time than this left

#: every Warp module of the kernel package, by name (``kernels/*.py``)
KERNEL_MODULES = {
    info.name: importlib.import_module(f"{kernel_package.__name__}.{info.name}")
    for info in sorted(pkgutil.iter_modules(kernel_package.__path__), key=lambda i: i.name)
}
#: the ``Batch`` fields compared between runs
BATCH_ARRAYS = ("heights", "sensor_z", "points", "scan", "mask", "target", "scan_max", "target_visible")


class SkipCheck(Exception):
    """Raised by a check that cannot run here; its message is the reason."""


class TimeUp(Exception):
    """Raised by a timing loop that finds the deadline already past."""


# ------------------------------------------------------------------------------ plan
@dataclass(frozen=True)
class Plan:
    """Sizes and repeats of one run; ``kind`` keys are ``"cpu"`` and ``"cuda"``."""

    quick: bool
    consistency_batch: int
    stream_batches: dict
    train_batches: dict
    warmup: dict
    repeats: dict
    train_steps: dict
    loop_cap_s: dict  # longest a timing loop goes on after its warm-up
    processes: int
    split_scan: bool
    switch_batch: dict  # the batch the kernel switches are compared at


def make_plan(quick: bool) -> Plan:
    """``quick``: batches 1 and 8, training at 8, few repeats (CI on a 2-core CPU); full:
    batches 1..1024 and training at 8/64/256 on CUDA, the CPU as quick with more repeats."""
    if quick:
        return Plan(quick=True, consistency_batch=2, stream_batches={"cpu": (1, 8), "cuda": (1, 8)},
                    train_batches={"cpu": (8,), "cuda": (8,)}, warmup={"cpu": 1, "cuda": 1}, repeats={"cpu": 3, "cuda": 5},
                    train_steps={"cpu": 2, "cuda": 3}, loop_cap_s={"cpu": 5.0, "cuda": 2.0}, processes=2, split_scan=False, switch_batch={"cpu": 2, "cuda": 8})
    return Plan(quick=False, consistency_batch=4, stream_batches={"cpu": (1, 8), "cuda": (1, 8, 64, 256, 1024)},
                train_batches={"cpu": (8,), "cuda": (8, 64, 256)}, warmup={"cpu": 1, "cuda": 3}, repeats={"cpu": 5, "cuda": 20},
                train_steps={"cpu": 3, "cuda": 10}, loop_cap_s={"cpu": 10.0, "cuda": 4.0},
                processes=max(2, min(4, os.cpu_count() or 2)), split_scan=True,
                switch_batch={"cpu": 8, "cuda": 256})


def parse_groups(only) -> tuple[str, ...]:
    """Check groups from None (all), ``"repeat,walks"`` or an iterable of names."""
    if only is None:
        return GROUPS
    names = [s.strip() for s in only.split(",")] if isinstance(only, str) else [str(s).strip() for s in only]
    names = [n for n in names if n]
    unknown = [n for n in names if n not in GROUPS]
    if unknown or not names:
        raise ValueError(f"only={only!r}: unknown or no check names; choose from {', '.join(GROUPS)}")
    return tuple(g for g in GROUPS if g in names)


def kind_of(device: str) -> str:
    return "cuda" if device.startswith("cuda") else "cpu"


# ------------------------------------------------------------------------------ environment
def cuda_unavailable_reason() -> str | None:
    """Why CUDA rows are skipped here, or None when Warp and torch both see a CUDA device."""
    resolve_device("cpu")  # wp.init(), quietly
    if not wp.is_cuda_available():
        return "no CUDA device (Warp finds no CUDA driver or GPU)"
    if not torch.cuda.is_available():
        build = "a CPU-only build" if torch.version.cuda is None else f"built for CUDA {torch.version.cuda}"
        return f"no CUDA device for torch {torch.__version__} ({build}): torch.cuda.is_available() is False"
    return None


def _version(v) -> str | None:
    if v is None:
        return None
    return ".".join(str(x) for x in v) if isinstance(v, (tuple, list)) else str(v)


def _nvidia_smi() -> str | None:
    """``nvidia-smi``'s one line per GPU (name, driver, memory), or None without it."""
    exe = shutil.which("nvidia-smi")
    if exe is None:
        return None
    try:
        out = subprocess.run([exe, "--query-gpu=name,driver_version,memory.total", "--format=csv,noheader"],
                             capture_output=True, text=True, timeout=15)
    except (OSError, subprocess.SubprocessError) as err:
        return f"nvidia-smi failed: {err}"
    return " | ".join(line.strip() for line in out.stdout.splitlines() if line.strip()) or None


def _gpus() -> list[dict]:
    gpus = []
    for i in range(torch.cuda.device_count()):
        props = torch.cuda.get_device_properties(i)
        gpu = {"device": f"cuda:{i}", "name": props.name, "memory_gib": props.total_memory / 2**30,
               "capability": f"{props.major}.{props.minor}", "multiprocessors": props.multi_processor_count}
        with contextlib.suppress(Exception):  # Warp's view of the same device, where Warp sees it
            d = wp.get_device(f"cuda:{i}")
            gpu.update(warp_name=str(d.name), warp_arch=int(d.arch), mempool=bool(wp.is_mempool_enabled(d)))
        gpus.append(gpu)
    return gpus


def describe_environment() -> dict:
    """Where the figures come from: software versions, the CPU, and each CUDA device."""
    env = environment("cpu")
    reason = cuda_unavailable_reason()
    get = lambda name: getattr(wp, name, lambda: None)  # noqa: E731 (older Warp lacks some)
    env = {
        "warp_terrain": __version__,
        "python": platform.python_version(),
        "python_executable": sys.executable,
        "platform": env["platform"],
        "cpu": env["device_name"],
        "cpu_count": env["cpu_count"],
        "torch": torch.__version__,
        "torch_cuda": torch.version.cuda,
        "cudnn": torch.backends.cudnn.version() if torch.cuda.is_available() else None,
        "warp": wp.config.version,
        "warp_devices": [str(d) for d in wp.get_devices()],
        "warp_kernel_cache": str(wp.config.kernel_cache_dir),
        "cuda": reason is None,
        "cuda_reason": reason,
        "cuda_driver": _version(get("get_cuda_driver_version")()) if wp.is_cuda_available() else None,
        "warp_cuda_toolkit": _version(get("get_cuda_toolkit_version")()) if wp.is_cuda_available() else None,
        "nvidia_smi": _nvidia_smi(),
        "gpus": _gpus() if reason is None else [],
    }
    return env


def format_environment(env: dict, quick: bool, time_limit_s: float) -> str:
    """The environment as a few lines for people."""
    lines = [
        f"warp-terrain {env['warp_terrain']} gpu-check{' --quick' if quick else ''}: time limit {time_limit_s:g} s",
        f"python {env['python']} ({env['python_executable']}) | torch {env['torch']} (CUDA build {env['torch_cuda'] or 'none'}, "
        f"cuDNN {env['cudnn'] or 'n/a'}) | warp {env['warp']}",
        f"CPU: {env['cpu']}, {env['cpu_count']} cores; {env['platform']}",
        f"Warp devices: {', '.join(env['warp_devices'])}; kernel cache {env['warp_kernel_cache']}",
    ]
    if env["cuda"]:
        lines.append(f"CUDA: driver {env['cuda_driver']}, Warp built with toolkit {env['warp_cuda_toolkit']}, torch CUDA {env['torch_cuda']}")
        for g in env["gpus"]:
            lines.append(f"GPU {g['device']}: {g['name']}, {g['memory_gib']:.1f} GiB, compute {g['capability']}, {g['multiprocessors']} SMs"
                         + (f", Warp mempool {'on' if g.get('mempool') else 'off'}" if "mempool" in g else ""))
    else:
        lines.append(f"CUDA: none ({env['cuda_reason']})")
    if env["nvidia_smi"]:
        lines.append(f"nvidia-smi: {env['nvidia_smi']}")
    return "\n".join(lines)


# ------------------------------------------------------------------------------ comparisons
def host_arrays(batch) -> dict[str, np.ndarray]:
    """A ``Batch``'s tensors copied to host numpy arrays (``target_visible`` when present)."""
    out = {}
    for name in BATCH_ARRAYS:
        t = getattr(batch, name, None)
        if t is not None:
            out[name] = t.detach().to("cpu").numpy().copy()
    return out


def bit_differences(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> dict[str, int]:
    """Per array: how many elements differ in any bit (NaN payloads and signed zeros count);
    -1 where an array is missing on one side or differs in shape or dtype."""
    diffs = {}
    for name in sorted(set(a) | set(b)):
        x, y = a.get(name), b.get(name)
        if x is None or y is None or x.shape != y.shape or x.dtype != y.dtype:
            diffs[name] = -1
            continue
        xb = np.ascontiguousarray(x).view(np.uint8).reshape(x.size, -1)
        yb = np.ascontiguousarray(y).view(np.uint8).reshape(y.size, -1)
        diffs[name] = int((xb != yb).any(axis=1).sum())
    return diffs


def _bit_failures(label: str, diffs: dict[str, int]) -> list[str]:
    return [f"{label}: {name} {'missing or reshaped' if n < 0 else f'differs in {n} values'}" for name, n in diffs.items() if n != 0]


def compare_points(a: np.ndarray, b: np.ndarray, atol: float = POINT_ATOL_M) -> dict:
    """Two ``(..., 3)`` scans of the same rays (NaN rows: no return): the share of rays that
    agree (both miss, or both hit within ``atol`` on each axis), hit shares and the largest
    difference between points both hit."""
    a = a.reshape(-1, 3)
    b = b.reshape(-1, 3)
    hit_a, hit_b = np.isfinite(a).all(-1), np.isfinite(b).all(-1)
    both = hit_a & hit_b
    gap = np.abs(a[both].astype(np.float64) - b[both]).max(-1) if both.any() else np.zeros(0)
    close = np.zeros(len(a), dtype=bool)
    close[both] = gap <= atol
    agree = (~hit_a & ~hit_b) | close
    return {
        "rays": int(len(a)),
        "hits_a": int(hit_a.sum()),
        "hits_b": int(hit_b.sum()),
        "hit_pattern_agreement": float((hit_a == hit_b).mean()) if len(a) else 1.0,
        "ray_agreement": float(agree.mean()) if len(a) else 1.0,
        "point_max_abs_m": float(gap.max()) if gap.size else 0.0,
    }


def _points_failures(label: str, f: dict) -> list[str]:
    bad = []
    if f["hits_a"] == 0 or f["hits_b"] == 0:
        bad.append(f"{label}: no returns to compare ({f['hits_a']} and {f['hits_b']} hits)")
    if f["ray_agreement"] < RAY_AGREEMENT_MIN:
        bad.append(f"{label}: {100 * f['ray_agreement']:.4f} % of rays agree (< {100 * RAY_AGREEMENT_MIN:.2f} %; "
                   f"largest point gap {1e3 * f['point_max_abs_m']:.3f} mm)")
    return bad


def compare_batches(ref: dict[str, np.ndarray], other: dict[str, np.ndarray]) -> tuple[dict, list[str]]:
    """Batches of the same settings and seed from two devices (host arrays): the figures and
    the criteria each misses (terrain and sensor heights to ``TERRAIN_ATOL_M``; rays as
    :func:`compare_points`; masks, scans where both observed, and targets)."""
    fig = {"terrain_max_abs_m": float(np.abs(ref["heights"].astype(np.float64) - other["heights"]).max()),
           "sensor_z_max_abs_m": float(np.abs(ref["sensor_z"].astype(np.float64) - other["sensor_z"]).max())}
    fig.update(compare_points(ref["points"], other["points"]))
    mask_a, mask_b = ref["mask"] > 0, other["mask"] > 0
    fig["mask_agreement"] = float((mask_a == mask_b).mean())
    both = mask_a & mask_b
    scan_gap = np.abs(ref["scan"][both].astype(np.float64) - other["scan"][both])
    fig["scan_agreement"] = float((scan_gap <= POINT_ATOL_M).mean()) if scan_gap.size else 1.0
    fig["scan_max_abs_m"] = float(scan_gap.max()) if scan_gap.size else 0.0
    fig["observed_cells"] = int(both.sum())
    for name in ("target", "target_visible"):
        if name in ref or name in other:
            if name not in ref or name not in other:
                fig[f"{name}_max_abs_m"] = math.inf
            else:
                fig[f"{name}_max_abs_m"] = float(np.abs(ref[name].astype(np.float64) - other[name]).max())
    bad = []
    for key in ("terrain_max_abs_m", "sensor_z_max_abs_m"):
        if not fig[key] <= TERRAIN_ATOL_M:
            bad.append(f"{key.removesuffix('_max_abs_m')} differs by {fig[key]:.3g} m (> {TERRAIN_ATOL_M:g})")
    bad += _points_failures("points", fig)
    if fig["mask_agreement"] < MASK_AGREEMENT_MIN:
        bad.append(f"masks agree on {100 * fig['mask_agreement']:.3f} % of cells (< {100 * MASK_AGREEMENT_MIN:.1f} %)")
    if fig["scan_agreement"] < SCAN_AGREEMENT_MIN:
        bad.append(f"scan heights agree to 1 mm on {100 * fig['scan_agreement']:.3f} % of cells (< {100 * SCAN_AGREEMENT_MIN:.1f} %)")
    for name in ("target", "target_visible"):
        key = f"{name}_max_abs_m"
        if key in fig and not fig[key] <= TARGET_ATOL_M:
            bad.append(f"{name} differs by {fig[key]:.3g} m (> {TARGET_ATOL_M:g})")
    return fig, bad


# ------------------------------------------------------------------------------ settings
def consistency_settings() -> dict[str, SimConfig]:
    """``octave5``: the default data; ``wide``: the widest synthetic world (tilt, relief,
    landforms, every obstacle kind, clutter, so the per-ray walk) with 5 % image noise."""
    wide = SimConfig(terrain=terrain_preset("wide"))
    wide.data.noise = 0.05
    return {"octave5": SimConfig(), "wide": wide}


def _seed() -> int:
    return SEED & 0x7FFFFFFF


def _batch(sim: SimConfig, batch: int, device: str) -> dict[str, np.ndarray]:
    return host_arrays(generate_batch(batch, sim, seed=SEED, device=device))


def _poison(device: str, nbytes: int) -> int:
    """Fill ``nbytes`` (in blocks from 4 KiB up) of fresh allocations on ``device`` with NaN and
    free them, so a later allocation that reads before writing finds NaN, not zeros or old
    results. Returns the bytes poisoned."""
    blocks, size, total = [], 1024, 0
    while total < nbytes:
        blocks.append(wp.full(size, value=float("nan"), dtype=wp.float32, device=device))
        total += 4 * size
        size = min(size * 2, max(1024, nbytes // 16))  # blocks of every size up to a quarter of nbytes
    wp.synchronize_device(device)
    del blocks
    return total


# ------------------------------------------------------------------------------ timing
@contextlib.contextmanager
def on_torch_stream(device: str):
    """On CUDA, Warp launches go to torch's current stream for the block (so torch's events
    bracket them); nothing on the CPU."""
    if kind_of(device) != "cuda":
        yield
        return
    with wp.ScopedStream(wp.stream_from_torch(torch.device(device))):
        yield


def timed(fn: Callable[[], object], device: str, warmup: int, repeats: int, cap_s: float, deadline: float) -> dict:
    """Seconds per call of ``fn`` on ``device``, after ``warmup`` calls (at least one; the last
    one, synchronised, estimates a call's time): up to ``repeats`` timed calls, as many as fit
    in ``cap_s`` and before the deadline (``time.monotonic()``) by that estimate, at least one.
    CUDA: CUDA events on torch's stream (Warp launched on it too), recorded without host syncs
    between calls and read after one final synchronisation; CPU: ``perf_counter`` per call.
    ``wall_s`` is the whole timed loop on the host clock, synchronised at both ends."""
    if time.monotonic() >= deadline:
        raise TimeUp("the time limit was reached before the timing loop")
    cuda = kind_of(device) == "cuda"
    with on_torch_stream(device):
        for _ in range(max(0, warmup - 1)):
            fn()
        sync_device(device)
        t = time.perf_counter()
        fn()
        sync_device(device)
        estimate = time.perf_counter() - t
        budget = min(cap_s, deadline - time.monotonic())
        n = max(1, min(int(repeats), int(budget / max(estimate, 1e-9))))
        t0 = time.perf_counter()
        if cuda:
            stream = torch.cuda.current_stream(torch.device(device))
            events = []
            for _ in range(n):
                start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
                start.record(stream)
                fn()
                end.record(stream)
                events.append((start, end))
            sync_device(device)
            times = [s.elapsed_time(e) / 1e3 for s, e in events]
        else:
            times = []
            for _ in range(n):
                t = time.perf_counter()
                fn()
                times.append(time.perf_counter() - t)
        wall = time.perf_counter() - t0
    return {"timer": "cuda_event" if cuda else "perf_counter", "warmup": max(1, warmup), "estimate_s": float(estimate), "repeats": len(times),
            "median_s": float(statistics.median(times)), "min_s": float(min(times)), "times_s": [float(t) for t in times],
            "wall_s": float(wall)}


def kernel_times(fn: Callable[[], object], device: str) -> dict[str, float]:
    """Milliseconds of each CUDA activity (kernels, memsets, copies; summed over launches of the
    same name, largest first) in one call of ``fn``: Warp's activity timing (CUDA only)."""
    wp.timing_begin(cuda_filter=wp.TIMING_KERNEL | wp.TIMING_MEMSET | wp.TIMING_MEMCPY)
    try:
        with on_torch_stream(device):
            fn()
    finally:
        results = wp.timing_end()
    totals: dict[str, float] = {}
    for r in results:
        totals[r.name] = totals.get(r.name, 0.0) + float(r.elapsed)
    return dict(sorted(totals.items(), key=lambda kv: -kv[1]))


# ------------------------------------------------------------------------------ checks
@dataclass
class Context:
    plan: Plan
    deadline: float  # the cooperative deadline (time.monotonic())


@dataclass
class Outcome:
    """What a check returns: its figures, one line for the table, and the criteria it missed."""

    figures: dict
    detail: str
    failures: list[str] = field(default_factory=list)


def check_compile(ctx: Context, device: str) -> Outcome:
    """Load every module of ``warp_terrain.kernels`` on ``device`` (compiling what Warp's
    kernel cache lacks), timed per module."""
    seconds, kernels = {}, {}
    kernel_type = getattr(wp, "Kernel", None)
    for name, module in KERNEL_MODULES.items():
        t0 = time.perf_counter()
        wp.load_module(module, device=device)
        seconds[name] = time.perf_counter() - t0
        kernels[name] = sum(isinstance(v, kernel_type) and getattr(v.func, "__module__", None) == module.__name__
                            for v in vars(module).values()) if kernel_type else None  # defined here, not imported
    wp.synchronize_device(device)
    total = sum(seconds.values())
    slowest = max(seconds, key=seconds.get)
    n_kernels = sum(k or 0 for k in kernels.values())
    figures = {"modules": len(seconds), "kernels": n_kernels, "seconds": seconds, "kernels_per_module": kernels, "total_s": total,
               "kernel_cache": str(wp.config.kernel_cache_dir)}
    return Outcome(figures, f"{len(seconds)} modules, {n_kernels} kernels in {total:.2f} s (slowest {slowest} {seconds[slowest]:.2f} s)")


def check_repeat(ctx: Context, device: str) -> Outcome:
    """Two ``generate_batch`` runs with the same seed are bit-identical, on each setting."""
    figures, bad = {}, []
    for label, sim in consistency_settings().items():
        a = _batch(sim, ctx.plan.consistency_batch, device)
        b = _batch(sim, ctx.plan.consistency_batch, device)
        figures[label] = {"batch": ctx.plan.consistency_batch, "differing_values": bit_differences(a, b)}
        bad += _bit_failures(label, figures[label]["differing_values"])
    return Outcome(figures, f"{', '.join(figures)}: {'bit-identical in every array' if not bad else 'differ'}", bad)


def check_poison(ctx: Context, device: str) -> Outcome:
    """A run made after freed memory was filled with NaN equals the run before, bit for bit
    (an output or scratch array read before it is written would show)."""
    figures, bad = {}, []
    for label, sim in consistency_settings().items():
        batch = generate_batch(ctx.plan.consistency_batch, sim, seed=SEED, device=device)
        nbytes = sum(int(a.capacity) for a in batch.warp_arrays.values())
        ref = host_arrays(batch)
        del batch
        poisoned = _poison(device, 4 * nbytes)
        other = _batch(sim, ctx.plan.consistency_batch, device)
        figures[label] = {"batch": ctx.plan.consistency_batch, "poisoned_bytes": poisoned, "differing_values": bit_differences(ref, other)}
        bad += _bit_failures(label, figures[label]["differing_values"])
    mib = sum(f["poisoned_bytes"] for f in figures.values()) / 2**20
    return Outcome(figures, f"{', '.join(figures)}: {'unchanged' if not bad else 'changed'} after {mib:.0f} MiB of NaN", bad)


def check_walks(ctx: Context, device: str) -> Outcome:
    """The column walk (``cast_columns``) against the per-ray walk (``cast_rays``) on the same
    terrains (the ``wide`` setting's, no clutter: its obstacles' walls are the hard cases)."""
    sim = consistency_settings()["wide"]
    seed = _seed()
    heights = make_terrains(ctx.plan.consistency_batch, sim, seed, device)
    reach = 0.5 * sim.data.map_size * sim.data.map_cell + sim.terrain.cell if sim.data.clip_rays else 0.0
    walks = {}
    for per_ray in (False, True):
        points, _ = trace(heights, sim.terrain.cell, sim.lidar, seed, device, augment=sim.data.augment, reach=reach, per_ray=per_ray)
        walks[per_ray] = wp.to_torch(points).detach().to("cpu").numpy().copy()
    figures = {"batch": ctx.plan.consistency_batch, "lidar": sim.lidar.name, **compare_points(walks[True], walks[False])}
    bad = _points_failures("column walk vs per-ray walk", figures)
    return Outcome(figures, f"{100 * figures['ray_agreement']:.3f} % of rays agree, largest gap {1e3 * figures['point_max_abs_m']:.3f} mm", bad)


def check_cuda_vs_cpu(ctx: Context, device: str) -> Outcome:
    """The same batches on CUDA and on the CPU, on each setting (:func:`compare_batches`)."""
    figures, bad = {}, []
    for label, sim in consistency_settings().items():
        cpu = _batch(sim, ctx.plan.consistency_batch, "cpu")
        gpu = _batch(sim, ctx.plan.consistency_batch, device)
        figures[label], misses = compare_batches(cpu, gpu)
        bad += [f"{label}: {m}" for m in misses]
    worst = lambda key: max(f[key] for f in figures.values())  # noqa: E731
    detail = (f"terrain {worst('terrain_max_abs_m'):.2g} m, rays {100 * min(f['ray_agreement'] for f in figures.values()):.3f} %, "
              f"points {1e3 * worst('point_max_abs_m'):.3f} mm, masks {100 * min(f['mask_agreement'] for f in figures.values()):.3f} %, "
              f"target {worst('target_max_abs_m'):.2g} m")
    return Outcome(figures, detail, bad)


def check_capture(ctx: Context, device: str) -> Outcome:
    """``BatchGraph`` (``sim/graph.py``: one batch recorded, then replayed per seed; a CUDA graph
    on CUDA) against ``generate_batch`` on each setting, for two seeds after the first: bit-identical.
    On CUDA the capture itself fails on any host sync among the launches, so a PASS there also
    shows ``generate_batch``'s launches free of syncs."""
    figures, bad = {}, []
    seeds = (_seed(), _seed() + 1, _seed() + 2)
    for label, sim in consistency_settings().items():
        graph = BatchGraph(ctx.plan.consistency_batch, sim, device)
        diffs = {}
        for seed in seeds:
            replayed = host_arrays(graph(seed))
            direct = host_arrays(generate_batch(ctx.plan.consistency_batch, sim, seed=seed, device=device))
            for name, n in bit_differences(direct, replayed).items():
                diffs[name] = diffs.get(name, 0) + n
        figures[label] = {"batch": ctx.plan.consistency_batch, "seeds": list(seeds), "cuda_graph": graph.graph is not None,
                          "arrays": len(graph.arena.arrays), "differing_values": diffs}
        bad += _bit_failures(label, diffs)
    how = "a CUDA graph" if any(f["cuda_graph"] for f in figures.values()) else "the recorded launches"
    return Outcome(figures, f"{', '.join(figures)}: replays of {how} {'equal generate_batch bit for bit' if not bad else 'differ'}", bad)


def check_no_sync(ctx: Context, device: str) -> Outcome:
    """No host sync in a training step: one optimiser step (D then G) of the default model on a
    fixed batch under ``torch.cuda.set_sync_debug_mode("error")``, after a warm-up step (the
    sync-free batch itself: the ``capture`` row). CUDA only: the CPU has no syncs to find."""
    cfg = RunConfig().model
    model = build_train_model(cfg, device)
    x, y = train_inputs(fixed_pair(8, device), cfg.in_channels, device)

    def step():
        model.set_input(x, y)
        model.optimize_parameters()

    step()
    sync_device(device)
    torch.cuda.set_sync_debug_mode("error")
    try:
        step()
        error = None
    except RuntimeError as err:
        error = str(err).splitlines()[0]
    finally:
        torch.cuda.set_sync_debug_mode(0)
    sync_device(device)
    figures = {"batch": 8, "model": cfg.name, "sync": error}
    if error is not None:
        return Outcome(figures, f"a training step synchronises: {error}", [f"training step synchronises with the host: {error}"])
    return Outcome(figures, f"one {cfg.name} training step without a host sync")


def check_process_split(ctx: Context, device: str) -> Outcome:
    """``sim/parallel.py`` on the CPU: a batch of terrains split by samples over processes
    equals one process's bit for bit; with the full check also a scan split by azimuth columns."""
    sim = SimConfig()
    size, n, seed = terrain_size(sim), max(ctx.plan.consistency_batch, ctx.plan.processes), _seed()
    one = make_heightfields(n, size, sim.terrain, seed, "cpu").numpy()
    t0 = time.perf_counter()
    with ProcessHeightfields(n, size, sim.terrain, seed=seed, processes=ctx.plan.processes) as terrains:
        split = terrains.make().copy()
    figures = {"processes": ctx.plan.processes, "batch": n,
               "heightfields": {"differing_values": bit_differences({"heights": one}, {"heights": split})["heights"],
                                "seconds_with_startup": time.perf_counter() - t0}}
    bad = _bit_failures("terrains split by samples", {"heights": figures["heightfields"]["differing_values"]})
    parts = ["terrains"]
    if ctx.plan.split_scan:
        reach = 0.5 * sim.data.map_size * sim.data.map_cell + sim.terrain.cell
        single, _ = trace(wp.array(one, dtype=float, device="cpu"), sim.terrain.cell, sim.lidar, seed, "cpu", reach=reach)
        single = single.numpy().reshape(n, -1, 3)
        t0 = time.perf_counter()
        with ProcessTracer(one, sim.terrain.cell, sim.lidar, seed=seed, processes=ctx.plan.processes, reach=reach) as tracer:
            points = tracer.cast().copy()
        diffs = bit_differences({"points": single}, {"points": points})["points"]
        figures["scan"] = {"differing_values": diffs, "seconds_with_startup": time.perf_counter() - t0}
        bad += _bit_failures("scan split by columns", {"points": diffs})
        parts.append("scan")
    return Outcome(figures, f"{' and '.join(parts)} over {ctx.plan.processes} processes: {'equal to one process' if not bad else 'differ'}", bad)


def check_stream(ctx: Context, device: str, batch: int) -> Outcome:
    """``generate_batch(batch, SimConfig())`` (HDL-32E, 121x121 maps): pairs/s of the whole
    call, scans/s of its ray-cast stage, and each stage's time."""
    sim = SimConfig()
    kind, plan, seed = kind_of(device), ctx.plan, _seed()
    loop = functools.partial(timed, device=device, warmup=plan.warmup[kind], repeats=plan.repeats[kind], cap_s=plan.loop_cap_s[kind],
                             deadline=ctx.deadline)
    whole = loop(lambda: generate_batch(batch, sim, seed=SEED, device=device))
    with on_torch_stream(device):
        heights = make_terrains(batch, sim, seed, device)
        points, sensor_z = scan_terrains(heights, sim, seed, device)
    graph = BatchGraph(batch, sim, device)
    replayed = loop(lambda: graph(SEED))
    stages = {
        "terrain": loop(lambda: make_terrains(batch, sim, seed, device)),
        "ray_cast": loop(lambda: scan_terrains(heights, sim, seed, device)),
        "maps": loop(lambda: make_maps(heights, points, sensor_z, sim, seed, device)),
    }
    figures = {"batch": batch, "lidar": sim.lidar.name, "rays_per_scan": sim.lidar.num_rays, "map_size": sim.data.map_size, **whole,
               "pairs_per_s": batch / whole["median_s"], "scans_per_s": batch / stages["ray_cast"]["median_s"],
               "rays_per_s": batch * sim.lidar.num_rays / stages["ray_cast"]["median_s"],
               "wall_pairs_per_s": batch * whole["repeats"] / whole["wall_s"],
               "stages_median_s": {k: v["median_s"] for k, v in stages.items()}, "stages": stages,
               "replayed": {**replayed, "pairs_per_s": batch / replayed["median_s"], "cuda_graph": graph.graph is not None}}
    detail = f"{figures['pairs_per_s']:,.0f} pairs/s, {figures['scans_per_s']:,.0f} scans/s (" + ", ".join(
        f"{k} {1e3 * v:.2f} ms" for k, v in figures["stages_median_s"].items()) + ")"
    detail += f"; replayed{' (CUDA graph)' if graph.graph is not None else ''} {figures['replayed']['pairs_per_s']:,.0f} pairs/s"
    if kind == "cuda":  # where the time goes, kernel by kernel
        figures["kernels_ms"] = kernel_times(lambda: generate_batch(batch, sim, seed=SEED, device=device), device)
    if kind == "cuda" and batch >= 64:
        figures["target_pairs_per_s"] = TARGET_PAIRS_PER_S
        figures["meets_target"] = max(figures["pairs_per_s"], figures["replayed"]["pairs_per_s"]) >= TARGET_PAIRS_PER_S
        detail += f"; target {TARGET_PAIRS_PER_S:,.0f}: {'met' if figures['meets_target'] else 'not met'}"
    return Outcome(figures, detail)


# the column walk's variants (``sim/switches.py``), each against the default
COLUMN_SWITCHES = {
    "static_tile": dict(static_tile=True),
    "deferred_writes": dict(deferred_writes=True),
    "static_tile+deferred_writes": dict(static_tile=True, deferred_writes=True),
}


def check_switches(ctx: Context, device: str, batch: int) -> Outcome:
    """Each kernel switch (``sim/switches.py``) against the default on the same terrains: the
    column walk's variants must give the same points bit for bit, the other fBm path the same
    heights to ``TERRAIN_ATOL_M``; each variant's time and its speed-up over the default."""
    sim = SimConfig()
    sim.lidar.range_noise_std, sim.lidar.dropout = 0.02, 0.05  # the deferred pass's noise and dropout on
    kind, plan, seed = kind_of(device), ctx.plan, _seed()
    loop = functools.partial(timed, device=device, warmup=plan.warmup[kind], repeats=plan.repeats[kind], cap_s=plan.loop_cap_s[kind],
                             deadline=ctx.deadline)

    def cast():
        return scan_terrains(heights, sim, seed, device)[0]

    def points_now() -> dict[str, np.ndarray]:
        with on_torch_stream(device):
            return {"points": wp.to_torch(cast()).detach().to("cpu").numpy().copy()}

    with on_torch_stream(device):
        heights = make_terrains(batch, sim, seed, device)
    reference = points_now()
    default = loop(cast)
    figures, bad = {"batch": batch, "lidar": sim.lidar.name, "ray_cast": {"default": default}}, []
    for name, switches in COLUMN_SWITCHES.items():
        with use_kernel_switches(**switches):
            diffs = bit_differences(reference, points_now())
            timing = loop(cast)
        figures["ray_cast"][name] = {**timing, "differing_values": diffs, "speedup": default["median_s"] / timing["median_s"]}
        bad += _bit_failures(name, diffs)
    table = KernelSwitches().fbm_table_on(device)
    flipped = "per-vertex wp.noise" if table else "lattice-gradient table"

    def terrain():
        return make_terrains(batch, sim, seed, device)

    with on_torch_stream(device):
        base = wp.to_torch(terrain()).detach().to("cpu").numpy().copy()
    base_time = loop(terrain)
    with use_kernel_switches(fbm_table=not table):
        with on_torch_stream(device):
            other = wp.to_torch(terrain()).detach().to("cpu").numpy().copy()
        other_time = loop(terrain)
    gap = float(np.abs(other - base).max())
    figures["terrain"] = {"default": base_time, "other_path": flipped,
                          "other": {**other_time, "max_abs_m": gap, "speedup": base_time["median_s"] / other_time["median_s"]}}
    if not gap <= TERRAIN_ATOL_M:
        bad.append(f"fBm via {flipped} differs by {gap:.2g} m (> {TERRAIN_ATOL_M:g})")
    detail = "ray cast " + ", ".join(f"{k} {v['speedup']:.2f}x" for k, v in figures["ray_cast"].items() if k != "default")
    detail += f"; fBm via {flipped} {figures['terrain']['other']['speedup']:.2f}x (max gap {gap:.1g} m)"
    return Outcome(figures, detail, bad)


@contextlib.contextmanager
def train_option(name: str):
    """A training speed option of the ``train`` rows on CUDA: ``bf16_autocast`` (the step under
    ``torch.autocast`` in bfloat16) or ``cudnn_benchmark`` (cuDNN picks its fastest kernels)."""
    if name == "bf16_autocast":
        with torch.autocast(device_type="cuda", dtype=torch.bfloat16):
            yield
    elif name == "cudnn_benchmark":
        with torch.backends.cudnn.flags(enabled=True, benchmark=True):
            yield
    else:
        raise ValueError(f"train option {name!r}: choose from {', '.join(TRAIN_OPTIONS)}")


TRAIN_OPTIONS = ("bf16_autocast", "cudnn_benchmark")


def check_train(ctx: Context, device: str, batch: int) -> Outcome:
    """Optimiser steps (D then G) of the default model (``RunConfig().model``) on one fixed
    batch of the default data: training pairs/s, no data time."""
    kind, plan = kind_of(device), ctx.plan
    if kind == "cuda":
        torch.cuda.empty_cache()  # what the previous batch size's model cached
    cfg = RunConfig().model
    model = build_train_model(cfg, device)
    x, y = train_inputs(fixed_pair(batch, device), cfg.in_channels, device)

    def step():
        model.set_input(x, y)
        model.optimize_parameters()

    timing = timed(step, device, warmup=plan.warmup[kind], repeats=plan.train_steps[kind], cap_s=plan.loop_cap_s[kind], deadline=ctx.deadline)
    figures = {"batch": batch, "model": {k: getattr(cfg, k) for k in ("name", "ngf", "ndf", "unet_depth", "in_channels", "residual", "norm")},
               **timing, "pairs_per_s": batch / timing["median_s"], "wall_pairs_per_s": batch * timing["repeats"] / timing["wall_s"]}
    detail = f"{figures['pairs_per_s']:,.1f} pairs/s ({1e3 * timing['median_s']:.1f} ms/step, {cfg.name} ngf {cfg.ngf})"
    if kind == "cuda":  # the speed options, each on its own; one the model cannot run is reported, not failed
        figures["options"] = {}
        for name in TRAIN_OPTIONS:
            try:
                with train_option(name):
                    t = timed(step, device, warmup=plan.warmup[kind], repeats=plan.train_steps[kind], cap_s=plan.loop_cap_s[kind],
                              deadline=ctx.deadline)
                figures["options"][name] = {**t, "pairs_per_s": batch / t["median_s"]}
            except RuntimeError as err:
                figures["options"][name] = {"error": _one_line(f"{type(err).__name__}: {err}")}
        detail += "; " + ", ".join(f"{k} " + (f"{v['pairs_per_s']:,.0f}" if "pairs_per_s" in v else "failed")
                                   for k, v in figures["options"].items())
    if kind == "cuda":
        figures["target_pairs_per_s"] = TARGET_TRAIN_PAIRS_PER_S
        figures["meets_target"] = figures["pairs_per_s"] >= TARGET_TRAIN_PAIRS_PER_S
        detail += f"; target {TARGET_TRAIN_PAIRS_PER_S:,.0f}: {'met' if figures['meets_target'] else 'not met'}"
    return Outcome(figures, detail)


# ------------------------------------------------------------------------------ the run
@dataclass
class Task:
    """One row: a check on one device (``run(ctx) -> Outcome``), or a SKIP with ``skip``."""

    name: str
    group: str
    device: str
    run: Callable[[Context], Outcome] | None
    skip: str | None = None


def plan_tasks(plan: Plan, groups: Iterable[str], cuda_device: str | None, cuda_reason: str | None) -> list[Task]:
    """The rows of a run, in order: compile, consistency (CPU then CUDA), CUDA against the CPU,
    throughput (CUDA first: its figures matter most under the time limit), the process split."""
    groups = set(groups)
    devices = [("cpu", None), (cuda_device or "cuda", cuda_reason)]
    tasks: list[Task] = []

    def add(group: str, name: str, device: str, fn, why: str | None) -> None:
        if group in groups:
            tasks.append(Task(name, group, device, None if why else fn, why))

    for group, fn in (("compile", check_compile), ("repeat", check_repeat), ("poison", check_poison), ("walks", check_walks)):
        for device, why in devices:
            add(group, group, device, functools.partial(fn, device=device), why)
    add("cuda_vs_cpu", "cuda_vs_cpu", devices[1][0], functools.partial(check_cuda_vs_cpu, device=devices[1][0]), cuda_reason)
    for device, why in devices:
        add("capture", "capture", device, functools.partial(check_capture, device=device), why)
    add("no_sync", "no_sync", devices[1][0], functools.partial(check_no_sync, device=devices[1][0]), cuda_reason)
    for device, why in reversed(devices):
        kind = kind_of(device)
        for b in plan.stream_batches[kind]:
            add("stream", f"stream b={b}", device, functools.partial(check_stream, device=device, batch=b), why)
        b = plan.switch_batch[kind]
        add("switches", f"switches b={b}", device, functools.partial(check_switches, device=device, batch=b), why)
        for b in plan.train_batches[kind]:
            add("train", f"train b={b}", device, functools.partial(check_train, device=device, batch=b), why)
    add("process_split", "process_split", "cpu", functools.partial(check_process_split, device="cpu"), None)
    return tasks


def _one_line(text: str, limit: int = 300) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


class GpuCheck:
    """One run of the check: ``GpuCheck(quick=True).run()`` -> the JSON-ready report.

    ``time_limit_s`` counts from ``started`` (``time.monotonic()``; default: now). ``only``:
    None or some of :data:`GROUPS`. ``progress(line)`` receives a line as each check starts and
    ends.
    """

    def __init__(self, quick: bool = False, time_limit_s: float = TIME_LIMIT_S, only=None,
                 progress: Callable[[str], None] | None = None, started: float | None = None):
        if isinstance(time_limit_s, bool) or not isinstance(time_limit_s, (int, float)) or not math.isfinite(time_limit_s) or time_limit_s <= 0:
            raise ValueError(f"time_limit_s={time_limit_s!r}: must be a number of seconds > 0")
        self.quick = bool(quick)
        self.groups = parse_groups(only)
        self.plan = make_plan(self.quick)
        self.time_limit_s = float(time_limit_s)
        self.started = time.monotonic() if started is None else float(started)
        self.deadline = self.started + self.time_limit_s
        self.progress = progress or (lambda line: None)
        self.environment: dict | None = None
        self.tasks: list[Task] = []
        self.results: list[dict | None] = []
        self.current: tuple[int, float] | None = None  # (task index, monotonic start)
        self.timed_out = False
        self.finished = False
        self._lock = threading.Lock()

    # -------------------------------------------------------------- pieces
    def collect_environment(self) -> dict:
        if self.environment is None:
            self.environment = describe_environment()
        return self.environment

    def _cooperative_deadline(self) -> float:
        return self.deadline - min(RESERVE_S, 0.1 * self.time_limit_s)

    def _row(self, task: Task, status: str, seconds: float, detail: str = "", reason: str | None = None, figures: dict | None = None) -> dict:
        return {"name": task.name, "group": task.group, "device": task.device, "status": status, "seconds": float(seconds),
                "detail": detail, "reason": reason, "figures": figures or {}}

    def _run_task(self, task: Task, ctx: Context) -> dict:
        if task.run is None:
            return self._row(task, SKIP, 0.0, reason=task.skip)
        t0 = time.perf_counter()
        try:
            out = task.run(ctx)
        except SkipCheck as err:
            return self._row(task, SKIP, time.perf_counter() - t0, reason=_one_line(err))
        except TimeUp as err:
            return self._row(task, SKIP, time.perf_counter() - t0, reason=f"not run: {_one_line(err)}")
        except Exception as err:  # a check that breaks is a finding, not the end of the run
            tb = traceback.format_exc()
            self.progress(f"gpu-check {task.name} on {task.device} raised:\n{tb}")
            return self._row(task, FAIL, time.perf_counter() - t0, reason=_one_line(f"{type(err).__name__}: {err}"),
                             figures={"traceback": tb.splitlines()[-25:]})
        seconds = time.perf_counter() - t0
        if out.failures:
            return self._row(task, FAIL, seconds, out.detail, _one_line("; ".join(out.failures), 600), out.figures)
        return self._row(task, PASS, seconds, out.detail, None, out.figures)

    # -------------------------------------------------------------- run
    def run(self, on_timeout: Callable[[dict], None] | None = None) -> dict:
        """Run every planned check; the report. With ``on_timeout``, a watchdog calls it with
        the report so far when the hard time limit passes during the run (it is expected to
        end the process; if it returns, the run goes on and its report says it timed out)."""
        timer = None
        if on_timeout is not None:
            timer = threading.Timer(max(0.0, self.deadline - time.monotonic()), self._fire, args=(on_timeout,))
            timer.daemon = True
            timer.start()
        try:
            env = self.collect_environment()
            cuda_reason = env["cuda_reason"]
            cuda_device = resolve_device("cuda") if cuda_reason is None else None
            tasks = plan_tasks(self.plan, self.groups, cuda_device, cuda_reason)
            with self._lock:
                self.tasks, self.results = tasks, [None] * len(tasks)
            ctx = Context(self.plan, self._cooperative_deadline())
            for i, task in enumerate(tasks):
                if task.run is not None and time.monotonic() > ctx.deadline - MIN_START_S:
                    row = self._row(task, SKIP, 0.0, reason="not run: the time limit was reached")
                else:
                    with self._lock:
                        self.current = (i, time.monotonic())
                    if task.run is not None:
                        self.progress(f"gpu-check {task.name} on {task.device} ...")
                    row = self._run_task(task, ctx)
                    if task.run is not None:
                        self.progress(f"gpu-check {task.name} on {task.device}: {row['status']} in {row['seconds']:.1f} s")
                with self._lock:
                    self.results[i] = row
                    self.current = None
        finally:
            if timer is not None:
                timer.cancel()
            with self._lock:
                self.finished = True
        return self.report()

    def _fire(self, on_timeout: Callable[[dict], None]) -> None:
        with self._lock:
            if self.finished:
                return
            self.timed_out = True
            snapshot = self._report_locked()
        on_timeout(snapshot)

    # -------------------------------------------------------------- report
    def report(self) -> dict:
        with self._lock:
            return self._report_locked()

    def _report_locked(self) -> dict:
        now = time.monotonic()
        rows = []
        for i, task in enumerate(self.tasks):
            row = self.results[i] if i < len(self.results) else None
            if row is None and self.current is not None and self.current[0] == i:
                ran = now - self.current[1]
                row = self._row(task, FAIL, ran, reason=f"did not finish within the {self.time_limit_s:g} s time limit (stopped after {ran:.1f} s)")
            elif row is None:
                row = self._row(task, SKIP, 0.0, reason="not run: the time limit was reached")
            rows.append(row)
        short = [r for r in rows if r["status"] == SKIP and (r["reason"] or "").startswith("not run: ")]
        if self.timed_out or short:
            elapsed = now - self.started
            rows.append({"name": "time_limit", "group": "time_limit", "device": "", "status": FAIL, "seconds": float(elapsed), "detail": "",
                         "reason": f"the {self.time_limit_s:g} s time limit was reached"
                                   + (f": {len(short)} check(s) not run" if short else "")
                                   + (", the check running then was stopped" if self.timed_out and self.current is not None else ""),
                         "figures": {}})
        counts = {s: sum(r["status"] == s for r in rows) for s in (PASS, FAIL, SKIP)}
        return {
            "tool": "warp-terrain gpu-check",
            "warp_terrain": __version__,
            "quick": self.quick,
            "groups": list(self.groups),
            "time_limit_s": self.time_limit_s,
            "elapsed_s": float(now - self.started),
            "timed_out": self.timed_out,
            "complete": self.finished and not self.timed_out and not short,
            "criteria": {"terrain_atol_m": TERRAIN_ATOL_M, "point_atol_m": POINT_ATOL_M, "ray_agreement_min": RAY_AGREEMENT_MIN,
                         "mask_agreement_min": MASK_AGREEMENT_MIN, "scan_agreement_min": SCAN_AGREEMENT_MIN, "target_atol_m": TARGET_ATOL_M,
                         "target_pairs_per_s": TARGET_PAIRS_PER_S, "target_train_pairs_per_s": TARGET_TRAIN_PAIRS_PER_S},
            "plan": {"consistency_batch": self.plan.consistency_batch, "stream_batches": {k: list(v) for k, v in self.plan.stream_batches.items()},
                     "train_batches": {k: list(v) for k, v in self.plan.train_batches.items()}, "processes": self.plan.processes},
            "environment": self.environment,
            "checks": rows,
            "counts": counts,
            "ok": counts[FAIL] == 0,
        }


def run_gpu_check(quick: bool = False, time_limit_s: float = TIME_LIMIT_S, only=None, progress=None) -> dict:
    """Run the check in this process (no hard stop); the report (see :class:`GpuCheck`)."""
    return GpuCheck(quick=quick, time_limit_s=time_limit_s, only=only, progress=progress).run()


# ------------------------------------------------------------------------------ output
def format_report(report: dict) -> str:
    """The PASS/FAIL/SKIP table: check, device, status, seconds, and the detail or reason."""
    rows = [(r["name"], r["device"], r["status"], f"{r['seconds']:.1f} s" if r["status"] != SKIP or r["seconds"] else "",
             r["detail"] if r["status"] == PASS else (r["reason"] or r["detail"])) for r in report["checks"]]
    head = ("check", "device", "status", "time", "detail")
    widths = [max(len(head[k]), *(len(row[k]) for row in rows)) if rows else len(head[k]) for k in range(4)]
    fmt = lambda row: "  ".join(str(c).ljust(w) for c, w in zip(row[:4], widths)) + "  " + row[4]  # noqa: E731
    c = report["counts"]
    lines = [fmt(head), fmt(tuple("-" * w for w in widths) + ("-" * 6,)), *(fmt(r) for r in rows)]
    lines.append(f"{c[PASS]} PASS, {c[FAIL]} FAIL, {c[SKIP]} SKIP in {report['elapsed_s']:.1f} s"
                 f" (limit {report['time_limit_s']:g} s){'' if report['complete'] else ', incomplete'}: {'ok' if report['ok'] else 'FAILED'}")
    return "\n".join(lines)


def _jsonable(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None if math.isnan(x) else ("inf" if x > 0 else "-inf")
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.generic,)):
        return _jsonable(x.item())
    return x


def write_report(report: dict, path) -> None:
    """The report as JSON at ``path``, written atomically (non-finite numbers as null/"inf")."""
    with atomic_open(path, "w") as f:
        json.dump(_jsonable(report), f, indent=2, allow_nan=False)
        f.write("\n")
