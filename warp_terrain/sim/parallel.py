"""One scan split across CPU processes: a Warp CPU launch runs on one thread.

``ProcessTracer`` keeps ``processes`` worker processes, worker ``k`` owning azimuth columns
``k, k + processes, ...`` (interleaved, so terrain on one side does not load one worker) (every ring of a column: ``kernels/raycast.py`` ``cast_columns``).
The heightfields and the points live in shared memory, wrapped as Warp arrays without copies,
so a cast moves no data between processes: the parent says "cast", each worker walks its
columns straight into the shared points array (building its own max-height tiles, as a fresh
terrain needs) and says "done". The result equals ``trace`` on one process bit for bit.

On CUDA one launch already fills the device; this is for CPUs (``warp-terrain bench`` uses it
to show what both cores do). Training splits work across processes by batch instead (the
stream's worker processes, ``training/stream.py``).
"""

from __future__ import annotations

import multiprocessing
import os
from multiprocessing import shared_memory

import numpy as np

from .lidar import LidarConfig
from .validation import require


def _share(shape: tuple[int, ...]) -> tuple[shared_memory.SharedMemory, np.ndarray]:
    shm = shared_memory.SharedMemory(create=True, size=max(1, int(np.prod(shape)) * 4))
    return shm, np.ndarray(shape, dtype=np.float32, buffer=shm.buf)


def _worker(conn, heights_name, heights_shape, points_name, points_shape, cell, lidar, seed, reach, columns, core):
    import warp as wp

    if core is not None and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {core})  # one worker per core: they never queue on the same one

    from .scan import trace

    wp.config.quiet = True
    wp.init()
    heights_shm = shared_memory.SharedMemory(name=heights_name)
    points_shm = shared_memory.SharedMemory(name=points_name)
    try:
        heights = wp.array(np.ndarray(heights_shape, dtype=np.float32, buffer=heights_shm.buf), dtype=float, device="cpu", copy=False)
        flat = np.ndarray(points_shape, dtype=np.float32, buffer=points_shm.buf)
        points = wp.array(flat.reshape(points_shape[0], -1, 3), dtype=wp.vec3, device="cpu", copy=False)

        def cast():
            trace(heights, cell, lidar, seed, "cpu", reach=reach, columns=columns, out=points)

        cast()  # load the module before the first timed cast
        conn.send("ready")
        while conn.recv() == "cast":
            cast()
            conn.send("done")
    finally:
        del heights, points, flat
        heights_shm.close()
        points_shm.close()
        conn.close()


class ProcessTracer:
    """``trace`` of ``heights`` ((batch, H, W) metres) split by azimuth columns over ``processes``
    CPU processes. ``cast()`` returns the ``(batch, rays, 3)`` points (a view of shared memory,
    valid until the next cast or ``close``). Use as a context manager."""

    def __init__(self, heights: np.ndarray, cell: float, lidar: LidarConfig, seed: int = 0, processes: int = 2, reach: float = 0.0):
        from .scan import columns_walkable

        heights = np.asarray(heights, dtype=np.float32)
        if heights.ndim == 2:
            heights = heights[None]
        require(heights.ndim == 3 and heights.shape[1] >= 2 and heights.shape[2] >= 2, "heights", f"shape {heights.shape}", "must be (H, W) or (batch, H, W)")
        require(bool(np.isfinite(heights).all()), "heights", "array", "must hold only finite heights")
        require(isinstance(processes, int) and processes >= 1, "processes", processes, "must be an integer >= 1")
        lidar.validate()
        require(columns_walkable(lidar), "lidar", lidar.name, "has a vertical ring: it cannot be split by columns")
        processes = min(processes, lidar.columns)
        self._heights_shm, shared_heights = _share(heights.shape)
        shared_heights[...] = heights
        self._points_shm, self._points = _share((heights.shape[0], lidar.num_rays * 3))
        self.points = self._points.reshape(heights.shape[0], lidar.num_rays, 3)
        cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
        cores = cores if len(cores) >= processes else []
        ctx = multiprocessing.get_context("spawn")
        self._workers = []
        try:
            for k in range(processes):
                parent, child = ctx.Pipe()
                args = (child, self._heights_shm.name, heights.shape, self._points_shm.name, self._points.shape,
                        float(cell), lidar, int(seed), float(reach), range(k, lidar.columns, processes), cores[k % len(cores)] if cores else None)
                proc = ctx.Process(target=_worker, args=args, daemon=True)
                proc.start()
                child.close()
                self._workers.append((proc, parent))
            for proc, conn in self._workers:
                if conn.recv() != "ready":
                    raise RuntimeError(f"tracer process {proc.pid} failed to start")
        except BaseException:
            self.close()
            raise

    def cast(self) -> np.ndarray:
        for _proc, conn in self._workers:
            conn.send("cast")
        for proc, conn in self._workers:
            try:
                if conn.recv() != "done":
                    raise RuntimeError(f"tracer process {proc.pid} did not finish its columns")
            except EOFError:
                raise RuntimeError(f"tracer process {proc.pid} died (exit code {proc.exitcode})") from None
        return self.points

    def close(self) -> None:
        for proc, conn in getattr(self, "_workers", []):
            try:
                conn.send("stop")
            except (BrokenPipeError, OSError):
                pass
            proc.join(timeout=10)
            if proc.is_alive():
                proc.kill()
            conn.close()
        self._workers = []
        for name in ("_heights_shm", "_points_shm"):
            shm = getattr(self, name, None)
            if shm is not None:
                self.points = self._points = None
                shm.close()
                shm.unlink()
                setattr(self, name, None)

    def __enter__(self) -> ProcessTracer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
