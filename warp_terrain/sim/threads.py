"""Warp CPU launches on several cores, from threads.

Warp runs a CPU launch on the calling thread, and it releases the GIL while the kernel runs
(the kernel is a ``ctypes`` call), so launches from two Python threads run on two cores at
once. A launch whose threads are independent can therefore be split into parts (azimuth
columns of a scan, samples of a batch) and launched from a small pool: the same kernel, the
same per-element seeds, the same result as one launch, bit for bit.

Threads cost almost nothing to hand work to (no process start, no shared memory), but they
share the process with torch's own thread pool: splitting pays for a launch of many
milliseconds (a full scan), not for a small one, hence :func:`split_threads`' ``min_work``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from threading import Lock

from ..core.checks import require

_pool: ThreadPoolExecutor | None = None
_pool_lock = Lock()


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity where the OS reports one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # macOS, Windows
        return max(1, os.cpu_count() or 1)


def split_threads(threads: int | None, work: int, min_work: int, device: str) -> int:
    """How many threads to launch ``work`` elements with: ``threads`` if given (an integer >= 1;
    1 on a GPU, where one launch already fills the device), else on the CPU as many cores as
    leave each thread at least ``min_work`` elements."""
    if threads is not None:
        require(isinstance(threads, int) and not isinstance(threads, bool) and threads >= 1, "threads", threads,
                "must be an integer >= 1, or None for every usable core where the work pays for it")
    if device != "cpu":
        return 1
    if threads is not None:
        return min(threads, max(work, 1))
    return max(1, min(usable_cores(), work // max(min_work, 1)))


def _executor(threads: int) -> ThreadPoolExecutor:
    """One pool for the process, grown when a caller asks for more threads than it has."""
    global _pool
    with _pool_lock:
        if _pool is None or _pool._max_workers < threads:
            old, _pool = _pool, ThreadPoolExecutor(max_workers=threads, thread_name_prefix="warp-terrain-cpu")
            if old is not None:
                old.shutdown(wait=False)
        return _pool


def run_parts(launch: Callable[[object], None], parts: Sequence[object]) -> None:
    """``launch(part)`` for every part: the first on the calling thread, the others on the pool,
    all at once; returns when all are done and re-raises the first error."""
    if len(parts) == 1:
        launch(parts[0])
        return
    futures = [_executor(len(parts) - 1).submit(launch, part) for part in parts[1:]]
    try:
        launch(parts[0])
    finally:
        for future in futures:
            future.result()
