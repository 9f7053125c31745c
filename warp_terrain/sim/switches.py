"""Kernel switches: other ways of running the simulator's kernels, each giving the same output
bit for bit, kept so that a GPU run can time them against each other (``warp-terrain gpu-check``,
group ``switches``) and the faster one can become the default there.

The defaults are what is fastest on the CPU. Switches apply to the calling thread's context
(a ``ContextVar``), like ``torch.backends`` flags scoped by a ``with`` block::

    with use_kernel_switches(deferred_writes=True):
        batch = generate_batch(64, device="cuda")
"""

from __future__ import annotations

import dataclasses
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass


@dataclass(frozen=True)
class KernelSwitches:
    """Which variant of each kernel runs (every variant gives the same output)."""

    # the column walk's tile size compiled in (``kernels/raycast.py`` ``TILE_CELLS``) instead of
    # passed at run time (a constant divisor and tile bounds the compiler can fold)
    static_tile: bool = False
    # the column walk stores each ray's distance; a per-ray pass (``write_returns``) applies
    # range noise, dropout, range gate and the sample's transform, out of the walk's registers
    deferred_writes: bool = False
    # the fBm's lattice-gradient path (``kernels/noise.py``: gradients read once per lattice
    # point, one thread per row of vertices) instead of ``wp.noise`` per vertex and octave;
    # None: on the CPU only
    fbm_table: bool | None = None

    def validate(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            allowed = (True, False, None) if f.name == "fbm_table" else (True, False)
            if value not in allowed or not isinstance(value, (bool, type(None))):
                raise ValueError(f"kernel switch {f.name}: must be one of {allowed}, got {value!r}")

    def fbm_table_on(self, device: str) -> bool:
        """Whether the lattice-gradient fBm runs on ``device``."""
        return device == "cpu" if self.fbm_table is None else self.fbm_table


DEFAULT = KernelSwitches()
_CURRENT: ContextVar[KernelSwitches | None] = ContextVar("warp_terrain_kernel_switches", default=None)


def kernel_switches() -> KernelSwitches:
    """The switches in force in this context."""
    return _CURRENT.get() or DEFAULT


@contextmanager
def use_kernel_switches(switches: KernelSwitches | None = None, **changes):
    """Run the ``with`` block with ``switches`` (default: the current ones) changed by
    ``changes`` (``KernelSwitches`` field names); the previous switches come back after it."""
    names = {f.name for f in dataclasses.fields(KernelSwitches)}
    unknown = sorted(set(changes) - names)
    if unknown:
        raise ValueError(f"kernel switches: unknown {', '.join(unknown)}; known: {', '.join(sorted(names))}")
    chosen = dataclasses.replace(switches if switches is not None else kernel_switches(), **changes)
    chosen.validate()
    token = _CURRENT.set(chosen)
    try:
        yield chosen
    finally:
        _CURRENT.reset(token)
