"""How much memory a batch needs, checked before any of it is allocated.

``batch_bytes`` adds up the arrays ``generate_batch`` allocates (terrains, max-height tiles,
ray hits, the binning accumulators, the maps and the ground truth) plus the terrain's scratch
(obstacle slots and landform draws, ``sim/terrain.py::scratch_bytes``: dozens of obstacles per
map are a few kB per sample, freed before the scan allocates, so they count only where they
exceed what the later stages take); ``check_batch_fits``
compares that with the device's free memory and refuses a batch that would not fit, with the
estimate in the message, instead of letting the machine swap or the allocator fail midway.
"""

from __future__ import annotations

import os

import warp as wp

from .scan import TILE

HEADROOM = 0.8  # a batch may use at most this fraction of the free memory


def batch_bytes(batch: int, terrain_size: int, rays: int, map_size: int, scratch: int = 0) -> int:
    """Bytes ``generate_batch`` allocates for ``batch`` pairs; ``scratch``: the terrain's
    transient bytes per sample (freed before the scan allocates, so the peak is the larger)."""
    tiles = ((terrain_size - 2) // TILE + 1) ** 2
    later = (
        4 * tiles  # max-height tiles
        + 12 * rays  # hits (vec3)
        + (8 + 4 + 4) * map_size**2  # binning: float64 sum, count, max
        + 4 * 4 * map_size**2  # scan, scan_max, mask, target
        + 4 * 8  # sensor height, terrain max, target min/max, noise range
    )
    per_sample = 4 * terrain_size**2 + max(later, int(scratch))  # heights, then the larger stage
    return batch * per_sample


def available_bytes(device: str) -> int | None:
    """Free memory of ``device`` in bytes (host RAM for ``cpu``); None where it cannot be told."""
    if str(device).startswith("cuda"):
        free = wp.get_device(device).free_memory
        return int(free) if free else None
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _gib(n: float) -> str:
    return f"{n / 2**30:.2f} GiB" if n >= 2**30 else f"{n / 2**20:.1f} MiB"


_FITTED: set[tuple] = set()  # shapes already found to fit: the stream asks every step


def check_batch_fits(batch: int, terrain_size: int, rays: int, map_size: int, device: str, scratch: int = 0) -> int:
    """Raise ValueError with the estimate if the batch would not fit ``device``; return the estimate.

    A shape that fitted once is not asked again (no query per training step)."""
    need = batch_bytes(batch, terrain_size, rays, map_size, scratch)
    key = (batch, terrain_size, rays, map_size, int(scratch), str(device))
    if key in _FITTED:
        return need
    free = available_bytes(device)
    if free is not None and need > HEADROOM * free:
        raise ValueError(
            f"batch={batch}: needs about {_gib(need)} on {device} ({_gib(need / batch)} per pair: terrain "
            f"{terrain_size}^2, {rays:,} rays, map {map_size}^2) but {_gib(free)} is free; lower the batch size"
        )
    _FITTED.add(key)
    return need
