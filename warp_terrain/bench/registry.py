"""The workload registry (:data:`BENCHMARKS`), the ``only`` selection and :func:`run_benchmarks`."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence

from ..sim import resolve_device
from .harness import environment
from .infer import bench_infer
from .loader import bench_loader
from .noise import bench_noise
from .rays import bench_rays
from .stream import bench_stream
from .train import bench_train

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


def run_benchmarks(device=None, only=None, quick: bool = False, progress: Callable[[str], None] | None = None,
                   track: Callable[[Sequence, str], Iterable] | None = None) -> dict:
    """Run the selected benchmarks (all by default) on ``device``; a JSON-ready dict.

    ``only``: None, ``"noise,rays,stream"`` or a list of those names. ``quick``: tiny workloads
    and fewer repeats (a smoke test, not a measurement). ``progress`` receives one line per step;
    ``track(names, "bench")``, if given, yields the workloads' names while showing progress.
    """
    names = parse_only(only)
    device = resolve_device(device)
    results = {}
    for name in names if track is None else track(names, "bench"):
        if progress:
            progress(f"bench {name} on {device}{' (quick)' if quick else ''} ...")
        t0 = time.perf_counter()
        results[name] = BENCHMARKS[name](device=device, quick=quick)
        if progress:
            progress(f"bench {name} done in {time.perf_counter() - t0:.1f} s")
    return {"environment": environment(device), "quick": bool(quick), "results": results}
