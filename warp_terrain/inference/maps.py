"""A reconstructed elevation map on disk: one compressed ``.npz`` (``write_map``).

The file holds the arrays of :meth:`~warp_terrain.inference.reconstructor.Reconstructor.reconstruct_all`
(``height`` and ``mask``, and ``uncertainty`` if the model predicts one: float32
``(S, S)`` arrays in the sensor frame) and ``map_cell``, the cell size in metres (float32).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..core.atomic import atomic_open
from ..core.geometry import MapGeometry

#: The arrays a map file may hold, in the order they are written; the first two are required.
MAP_ARRAYS = ("height", "mask", "uncertainty")


def _check_result(result: Mapping, geometry: MapGeometry) -> None:
    missing = [key for key in MAP_ARRAYS[:2] if key not in result]
    if missing:
        raise ValueError(f"result: missing {', '.join(missing)} (expected the arrays of Reconstructor.reconstruct_all)")
    unknown = sorted(set(result) - set(MAP_ARRAYS))
    if unknown:
        raise ValueError(f"result: unknown arrays {', '.join(unknown)}; a map file holds {', '.join(MAP_ARRAYS)}")
    shape = (geometry.size, geometry.size)
    for key in result:
        if np.shape(result[key]) != shape:
            raise ValueError(f"result[{key!r}]: shape {np.shape(result[key])} is not the map's {shape}")


def write_map(path: str | os.PathLike, result: Mapping[str, np.ndarray], geometry: MapGeometry) -> Path:
    """Write ``result`` (``height``, ``mask``, optional ``uncertainty``) of a map of ``geometry``
    to ``path`` (``.npz``, compressed), atomically; returns the path. A wrong suffix, missing or
    unknown arrays or shapes other than ``(geometry.size, geometry.size)`` raise ValueError
    before anything is written."""
    path = Path(path)
    if path.suffix != ".npz":
        raise ValueError(f"path={str(path)!r}: must end in .npz")
    _check_result(result, geometry)
    arrays = {key: result[key] for key in MAP_ARRAYS if key in result}
    with atomic_open(path) as f:
        np.savez_compressed(f, **arrays, map_cell=np.float32(geometry.cell))
    return path
