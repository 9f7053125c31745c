"""The seed in device memory, and an arena that keeps a batch's arrays from one run to the next.

Every simulator kernel reads the batch seed from a one-element device array (``Seed.array``),
not from a launch argument, so a launch sequence recorded once (a CUDA graph:
``sim/graph.py``) draws a new batch whenever that array is rewritten before a replay.

The simulator allocates its scratch and output arrays through :func:`empty`, :func:`zeros`,
:func:`full` and :func:`upload`. Outside an :class:`Arena` these allocate as usual. Inside one,
the first run *records* every array in order; every later run *replays*: the k-th request gets
the k-th recorded array back (re-zeroed or re-filled on the device where asked), so the run
allocates nothing, reads nothing back to the host and launches the same kernels on the same
arrays: what CUDA graph capture needs. A replayed upload compares the host values with the ones
recorded and copies nothing (they must not change: a batch whose host-side inputs change is
not fixed and cannot be replayed).
"""

from __future__ import annotations

from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass

import numpy as np
import warp as wp


@dataclass
class Seed:
    """A batch seed: ``value`` on the host (host-side draws: DEM windows, domain randomisation)
    and the same in device memory (``array``, one int32), which every kernel reads."""

    value: int
    array: wp.array


def as_seed(seed, device: str) -> Seed:
    """``seed`` (an int, or a :class:`Seed` passed through) as a :class:`Seed` on ``device``."""
    if isinstance(seed, Seed):
        return seed
    value = int(seed)
    return Seed(value, full(1, value, int, device))


class Arena:
    """The arrays of one fixed-shape batch, recorded on the first run and handed out again on
    every later one (see the module's docstring). Use as ``with arena.run(): ...``."""

    def __init__(self) -> None:
        self.arrays: list[tuple[wp.array, bytes | None]] = []
        self.recorded = False
        self._cursor = 0

    @contextmanager
    def run(self):
        """One run of the batch: recording if nothing is recorded yet, else replaying."""
        self._cursor = 0
        token = _CURRENT.set(self)
        try:
            yield self
        finally:
            _CURRENT.reset(token)
        if not self.recorded:
            self.recorded = True
        elif self._cursor != len(self.arrays):
            raise RuntimeError(f"arena: this run asked for {self._cursor} arrays, the recorded run for {len(self.arrays)}")

    def _take(self, make, shape, dtype, device, host: np.ndarray | None = None) -> tuple[wp.array, bool]:
        """The next array: made (recording) or the recorded one (replaying); whether it is new."""
        if not self.recorded:
            arr = make()
            self.arrays.append((arr, None if host is None else host.tobytes()))
            return arr, True
        if self._cursor >= len(self.arrays):
            raise RuntimeError(f"arena: this run asks for more arrays than the {len(self.arrays)} recorded (the batch is not fixed)")
        arr, recorded_host = self.arrays[self._cursor]
        self._cursor += 1
        shape = (shape,) if isinstance(shape, int) else tuple(shape)
        if tuple(arr.shape) != shape or arr.dtype != dtype or str(arr.device) != str(wp.get_device(device)):
            raise RuntimeError(f"arena: array {self._cursor - 1} was recorded as {tuple(arr.shape)} {arr.dtype.__name__} on {arr.device}, "
                               f"this run asks for {shape} {dtype.__name__} on {device} (the batch is not fixed)")
        if host is not None and host.tobytes() != recorded_host:
            raise RuntimeError(f"arena: upload {self._cursor - 1} holds other values than when recorded (the batch's host inputs changed)")
        return arr, False


_CURRENT: ContextVar[Arena | None] = ContextVar("warp_terrain_arena", default=None)


def current_arena() -> Arena | None:
    return _CURRENT.get()


def _dtype(dtype):
    """Warp's dtype for ``dtype`` (Python's ``int`` and ``float`` are Warp's int32 and float32)."""
    return {int: wp.int32, float: wp.float32}.get(dtype, dtype)


def empty(shape, dtype, device: str) -> wp.array:
    """An uninitialised array (the arena's, inside one)."""
    dtype = _dtype(dtype)
    arena = current_arena()
    if arena is None:
        return wp.empty(shape, dtype=dtype, device=device)
    return arena._take(lambda: wp.empty(shape, dtype=dtype, device=device), shape, dtype, device)[0]


def zeros(shape, dtype, device: str) -> wp.array:
    """A zeroed array (the arena's, zeroed again on the device when replayed)."""
    dtype = _dtype(dtype)
    arena = current_arena()
    if arena is None:
        return wp.zeros(shape, dtype=dtype, device=device)
    arr, new = arena._take(lambda: wp.zeros(shape, dtype=dtype, device=device), shape, dtype, device)
    if not new:
        arr.zero_()
    return arr


def full(shape, value, dtype, device: str) -> wp.array:
    """An array filled with ``value`` (the arena's, filled again on the device when replayed:
    the value is then part of the recorded launches)."""
    dtype = _dtype(dtype)
    arena = current_arena()
    if arena is None:
        return wp.full(shape, value, dtype=dtype, device=device)
    arr, new = arena._take(lambda: wp.full(shape, value, dtype=dtype, device=device), shape, dtype, device)
    if not new:
        arr.fill_(value)
    return arr


def upload(host, dtype, device: str) -> wp.array:
    """``host`` (numpy, or a list of Warp structs) on the device (the arena's recorded copy when
    replayed: the values must be the ones recorded)."""
    dtype = _dtype(dtype)
    arena = current_arena()
    if arena is None:
        return wp.array(host, dtype=dtype, device=device)
    if isinstance(host, np.ndarray):
        shape, key = host.shape, np.ascontiguousarray(host)
    else:  # Warp structs: compared by their bytes
        shape, key = (len(host),), np.frombuffer(b"".join(bytes(memoryview(s._ctype)) for s in host), np.uint8)
    return arena._take(lambda: wp.array(host, dtype=dtype, device=device), shape, dtype, device, host=key)[0]
