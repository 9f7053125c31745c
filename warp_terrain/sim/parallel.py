"""Batched Warp CPU work split across processes: a Warp CPU launch runs on one thread.

Worker processes (spawned, pinned one per core) each own a share of the work and keep their
inputs and outputs in shared memory, wrapped as Warp arrays without copies, so a run moves no
data between processes: the parent says "run", each worker fills its share of the shared
output in place and says "done". Results equal one process's bit for bit.

- ``ProcessTracer``: one scan, worker ``k`` walking azimuth columns ``k, k + n, ...`` (every
  ring of a column: ``kernels/raycast.py`` ``cast_columns``; interleaved so that terrain on one
  side does not load one worker). Each builds its own max-height tiles, as a fresh terrain needs.
- ``ProcessHeightfields``: a batch of fBm heightfields, worker ``k`` making a contiguous range
  of samples (sample ``first + b`` is the same terrain in any batch).

On CUDA one launch already fills the device; these are for CPUs (``warp-terrain bench`` shows
what both cores do with them). Training splits work by batch in its stream's worker processes
(``training/stream.py``).
"""

from __future__ import annotations

import multiprocessing
import os
from multiprocessing import shared_memory

import numpy as np
import warp as wp

from ..core.checks import require
from .device import init_warp
from .lidar import LidarConfig
from .scan import columns_walkable, trace
from .terrain import TerrainConfig, make_heightfields


def _share(shape: tuple[int, ...]) -> tuple[shared_memory.SharedMemory, np.ndarray]:
    shm = shared_memory.SharedMemory(create=True, size=max(1, int(np.prod(shape)) * 4))
    return shm, np.ndarray(shape, dtype=np.float32, buffer=shm.buf)


def _attach(name: str, shape: tuple[int, ...]) -> tuple[shared_memory.SharedMemory, np.ndarray]:
    shm = shared_memory.SharedMemory(name=name)
    return shm, np.ndarray(shape, dtype=np.float32, buffer=shm.buf)


# ------------------------------------------------------------------ jobs (run in the workers)
def _trace_job(heights_name, heights_shape, points_name, points_shape, cell, lidar, seed, reach, columns):
    shms, views = zip(_attach(heights_name, heights_shape), _attach(points_name, points_shape))
    heights = wp.array(views[0], dtype=float, device="cpu", copy=False)
    points = wp.array(views[1].reshape(points_shape[0], -1, 3), dtype=wp.vec3, device="cpu", copy=False)

    def run():
        trace(heights, cell, lidar, seed, "cpu", reach=reach, columns=columns, out=points)

    return run, shms


def _terrain_job(heights_name, heights_shape, cfg, seed, first, stop):
    shm, view = _attach(heights_name, heights_shape)
    mine = wp.array(view[first:stop], dtype=float, device="cpu", copy=False)

    def run():
        make_heightfields(stop - first, heights_shape[1], cfg, seed, "cpu", first=first, out=mine)

    return run, (shm,)


def _serve(conn, job, args, core):
    """A worker: pin to ``core``, set the job up, then run it each time the parent asks."""
    if core is not None and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {core})  # one worker per core: they never queue on the same one
    wp.config.quiet = True
    init_warp()  # without the no-CUDA-driver warning on a CPU machine
    run, shms = job(*args)
    try:
        run()  # load the module before the first timed run
        conn.send("ready")
        while conn.recv() == "run":
            run()
            conn.send("done")
    finally:
        del run
        for shm in shms:
            shm.close()
        conn.close()


class _Workers:
    """Worker processes, one per (job, args); ``run()`` returns when all have finished."""

    def __init__(self, jobs: list[tuple]):
        cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
        cores = cores if len(cores) >= len(jobs) else []
        ctx = multiprocessing.get_context("spawn")
        self._procs = []
        try:
            for k, (job, args) in enumerate(jobs):
                parent, child = ctx.Pipe()
                proc = ctx.Process(target=_serve, args=(child, job, args, cores[k] if cores else None), daemon=True)
                proc.start()
                child.close()
                self._procs.append((proc, parent))
            self._collect("ready")
        except BaseException:
            self.close()
            raise

    def _collect(self, word: str) -> None:
        for proc, conn in self._procs:
            try:
                reply = conn.recv()
            except EOFError:
                raise RuntimeError(f"worker process {proc.pid} died (exit code {proc.exitcode})") from None
            if reply != word:
                raise RuntimeError(f"worker process {proc.pid} answered {reply!r}, expected {word!r}")

    def run(self) -> None:
        for _proc, conn in self._procs:
            conn.send("run")
        self._collect("done")

    def close(self) -> None:
        for proc, conn in self._procs:
            try:
                conn.send("stop")
            except (BrokenPipeError, OSError):
                pass
            proc.join(timeout=10)
            if proc.is_alive():
                proc.kill()
            conn.close()
        self._procs = []


class _Shared:
    """Owns shared-memory blocks and the workers using them; a context manager."""

    _workers: _Workers | None = None
    _shms: tuple = ()

    def _start(self, jobs: list[tuple]) -> None:
        try:
            self._workers = _Workers(jobs)
        except BaseException:  # a worker failed to start: free the shared memory too
            self.close()
            raise

    def close(self) -> None:
        if self._workers is not None:
            self._workers.close()
            self._workers = None
        for shm in self._shms:
            shm.close()
            shm.unlink()
        self._shms = ()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _check_processes(processes) -> None:
    require(isinstance(processes, int) and not isinstance(processes, bool) and processes >= 1, "processes", processes, "must be an integer >= 1")


class ProcessTracer(_Shared):
    """``trace`` of ``heights`` ((batch, H, W) metres) split by azimuth columns over ``processes``
    CPU processes. ``cast()`` returns the ``(batch, rays, 3)`` points (a view of shared memory,
    valid until the next cast or ``close``)."""

    def __init__(self, heights: np.ndarray, cell: float, lidar: LidarConfig, seed: int = 0, processes: int = 2, reach: float = 0.0):
        heights = np.asarray(heights, dtype=np.float32)
        if heights.ndim == 2:
            heights = heights[None]
        require(heights.ndim == 3 and heights.shape[1] >= 2 and heights.shape[2] >= 2, "heights", f"shape {heights.shape}", "must be (H, W) or (batch, H, W)")
        require(bool(np.isfinite(heights).all()), "heights", "array", "must hold only finite heights")
        _check_processes(processes)
        lidar.validate()
        require(columns_walkable(lidar), "lidar", lidar.name, "has a vertical ring: it cannot be split by columns")
        processes = min(processes, lidar.columns)
        heights_shm, shared_heights = _share(heights.shape)
        shared_heights[...] = heights
        points_shm, flat = _share((heights.shape[0], lidar.num_rays * 3))
        self._shms = (heights_shm, points_shm)
        self.points = flat.reshape(heights.shape[0], lidar.num_rays, 3)
        jobs = [(_trace_job, (heights_shm.name, heights.shape, points_shm.name, flat.shape, float(cell), lidar, int(seed),
                              float(reach), range(k, lidar.columns, processes))) for k in range(processes)]
        self._start(jobs)

    def cast(self) -> np.ndarray:
        self._workers.run()
        return self.points


class ProcessHeightfields(_Shared):
    """``make_heightfields(batch, size, cfg, seed, "cpu")`` split by samples over ``processes``
    CPU processes. ``make()`` returns the ``(batch, size, size)`` heights (a view of shared
    memory, valid until the next call or ``close``)."""

    def __init__(self, batch: int, size: int, cfg: TerrainConfig, seed: int = 0, processes: int = 2):
        require(isinstance(batch, int) and batch >= 1, "batch", batch, "must be an integer >= 1")
        require(isinstance(size, int) and size >= 2, "size", size, "must be an integer >= 2")
        _check_processes(processes)
        cfg.validate()
        processes = min(processes, batch)
        shm, self.heights = _share((batch, size, size))
        self._shms = (shm,)
        bounds = np.linspace(0, batch, processes + 1).round().astype(int)
        jobs = [(_terrain_job, (shm.name, self.heights.shape, cfg, int(seed), int(bounds[k]), int(bounds[k + 1]))) for k in range(processes)]
        self._start(jobs)

    def make(self) -> np.ndarray:
        self._workers.run()
        return self.heights
