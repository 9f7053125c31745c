"""The measurement harness every workload uses: the fixed seed, device synchronisation, timed
repeats after a warm-up, torch thread scoping, the environment and the result record."""

from __future__ import annotations

import contextlib
import os
import platform
import statistics
import time
from collections.abc import Callable
from importlib import metadata

import torch
import warp as wp

from ..core.version import __version__
from ..sim import resolve_device

SEED = 12345


def sync_device(device: str) -> None:
    """Wait for Warp's and torch's work on ``device``."""
    wp.synchronize_device(device)
    if device.startswith("cuda"):
        torch.cuda.synchronize(device)


def time_calls(fn: Callable[[], object], device: str, repeats: int, warmup: int = 1) -> list[float]:
    """Seconds per call of ``fn`` over ``repeats`` calls, after ``warmup`` untimed calls."""
    for _ in range(warmup):
        fn()
    sync_device(device)
    times = []
    for _ in range(repeats):
        sync_device(device)
        t0 = time.perf_counter()
        fn()
        sync_device(device)
        times.append(time.perf_counter() - t0)
    return times


def summarize(times: list[float]) -> dict:
    """Median, minimum, count and every time of a list of seconds."""
    return {
        "median_s": float(statistics.median(times)),
        "min_s": float(min(times)),
        "repeats": len(times),
        "times_s": [float(t) for t in times],
    }


@contextlib.contextmanager
def torch_threads(n: int):
    """torch's intra-op thread count set to ``n`` for the block, then restored."""
    before = torch.get_num_threads()
    torch.set_num_threads(int(n))
    try:
        yield
    finally:
        torch.set_num_threads(before)


def unavailable(module: str, err: BaseException) -> dict:
    """An anchor that cannot run here: reported, not raised."""
    return {"available": False, "reason": f"{module} not importable ({type(err).__name__}: {' '.join(str(err).split())})"}


def dist_version(*dists: str) -> str:
    """The installed version of the first of ``dists`` that is installed (a library can ship
    under several distribution names: ``open3d``, ``open3d-cpu``), or ``"unknown"``."""
    for dist in dists:
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            continue
    return "unknown"


def _cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo, or "" where there is none."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return ""


def _device_name(device: str) -> str:
    if device.startswith("cuda"):
        return str(wp.get_device(device).name)
    return _cpu_model() or platform.processor() or platform.machine() or "CPU"


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


def workload_result(name: str, device: str, params: dict, **values) -> dict:
    """A workload's record: its name, parameters, device and versions, then ``values``."""
    env = environment(device)
    return {"workload": name, "params": params, "device": device, "device_name": env["device_name"],
            "warp": env["warp"], "torch": env["torch"], **values}
