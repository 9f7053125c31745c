"""A reconstructed elevation map on disk (``write_map``): a compressed ``.npz``, or a GeoTIFF.

The format follows the path's suffix (``MAP_SUFFIXES``):

- ``.npz``: the arrays of :meth:`~warp_terrain.inference.reconstructor.Reconstructor.reconstruct_all`
  (``height`` and ``mask``, and ``uncertainty`` if the model predicts one: float32 ``(S, S)``
  arrays in the sensor frame) and ``map_cell``, the cell size in metres (float32).
- ``.tif`` / ``.tiff``: a GeoTIFF (rasterio, the ``[dem]`` extra) of three float32 bands,
  ``height`` (m), ``mask`` (1 observed, 0 not) and ``uncertainty`` (sigma, m; NaN, the nodata
  value, where the model predicts none), north up. Its geotransform places the map where the
  cloud was: in the frame the points were given in (the sensor frame itself, or the frame a
  points -> sensor ``transform`` starts from, e.g. UTM), with ``crs`` when given; heights are z
  in that same frame. Map cell ``(p, q)`` (x index ``p``, y index ``q``, see
  :mod:`warp_terrain.core.geometry`) is raster row ``S-1-q``, column ``p``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..core.atomic import atomic_open, atomic_path
from ..core.geometry import MapGeometry

#: The arrays a map file may hold, in the order they are written; the first two are required.
MAP_ARRAYS = ("height", "mask", "uncertainty")
#: Map-file suffixes and the format each one writes.
MAP_SUFFIXES = {".npz": "npz", ".tif": "tif", ".tiff": "tif"}
#: The GeoTIFF's bands: (description, unit), in band order 1, 2, 3.
GEOTIFF_BANDS = (("height (m)", "m"), ("mask (1 = observed, 0 = not)", ""), ("uncertainty sigma (m)", "m"))
GEOTIFF_INSTALL = "pip install 'warp-terrain[dem]' (rasterio)"
_FLAT_TOL = 1e-6  # how far a transform's rotation may be from a turn about z (radians, about)


def map_format(path: str | os.PathLike) -> str:
    """``"npz"`` or ``"tif"`` for a map path by its suffix (case-insensitive); ValueError otherwise."""
    suffix = Path(path).suffix.lower()
    if suffix not in MAP_SUFFIXES:
        raise ValueError(f"path={str(path)!r}: must end in {', '.join(MAP_SUFFIXES)} (.npz arrays or a GeoTIFF)")
    return MAP_SUFFIXES[suffix]


def need_rasterio():
    """The rasterio module, or ValueError saying how to install it."""
    try:
        import rasterio
    except ImportError:
        raise ValueError(f"writing a GeoTIFF needs rasterio: {GEOTIFF_INSTALL}") from None
    return rasterio


def check_crs(crs):
    """A ``rasterio.crs.CRS`` from ``crs`` ("EPSG:32633", WKT, a PROJ string or a CRS), None for
    None; ValueError naming it when rasterio does not know it."""
    if crs is None:
        return None
    rasterio = need_rasterio()
    try:
        return rasterio.crs.CRS.from_user_input(crs)
    except Exception as err:  # noqa: BLE001  (CRSError and whatever PROJ raises)
        first = (str(err).strip().splitlines() or [type(err).__name__])[0][:200]
        raise ValueError(f"crs={crs!r}: not a coordinate reference system ({first})") from None


def sensor_pose(transform=None) -> np.ndarray:
    """The sensor -> source-frame 4x4 pose: the inverse of a points -> sensor ``transform``
    (identity for None). A GeoTIFF lies in one horizontal plane, so the transform may only
    turn about z (and shift): a tilt (roll, pitch) raises ValueError."""
    if transform is None:
        return np.eye(4)
    m = np.asarray(transform, dtype=np.float64)
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise ValueError(f"transform: expected a finite 4x4 matrix, got shape {m.shape}")
    try:
        pose = np.linalg.inv(m)
    except np.linalg.LinAlgError:
        raise ValueError("transform: the matrix is singular (not a pose)") from None
    if max(abs(pose[0, 2]), abs(pose[1, 2]), abs(pose[2, 0]), abs(pose[2, 1]), abs(pose[2, 2] - 1.0)) > _FLAT_TOL:
        raise ValueError("transform: it tilts the cloud (roll/pitch, or mixes z with x/y); a GeoTIFF's georeference "
                         "needs a turn about z only (x,y,z,0,0,yaw), or write the sensor-frame map as .npz")
    return pose


def map_geotransform(geometry: MapGeometry, transform=None) -> tuple[tuple[float, float, float, float, float, float], float]:
    """``((a, b, c, d, e, f), z_offset)``: the GeoTIFF's affine (x = a*col + b*row + c,
    y = d*col + e*row + f, at pixel corners: rasterio's ``Affine(a, b, c, d, e, f)``) in the
    frame the points were given in, and what to add to sensor-frame heights to get z in that
    frame. ``transform``: the points -> sensor matrix (None: the cloud was in the sensor frame,
    so the affine is north-up in local metres centred on the sensor)."""
    pose = sensor_pose(transform)
    cell, half = float(geometry.cell), float(geometry.half_extent)
    # pixel (col, row) corner -> sensor (x, y) = (-half + col*cell, half - row*cell) -> pose
    a, b = pose[0, 0] * cell, -pose[0, 1] * cell
    d, e = pose[1, 0] * cell, -pose[1, 1] * cell
    c = -pose[0, 0] * half + pose[0, 1] * half + pose[0, 3]
    f = -pose[1, 0] * half + pose[1, 1] * half + pose[1, 3]
    return tuple(float(v) for v in (a, b, c, d, e, f)), float(pose[2, 3])


def north_up(grid) -> np.ndarray:
    """A map array ``[p, q]`` (x, y) as raster rows and columns: row 0 the largest y, column the x index."""
    return np.ascontiguousarray(np.asarray(grid).T[::-1])


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


def write_map(path: str | os.PathLike, result: Mapping[str, np.ndarray], geometry: MapGeometry, *,
              transform=None, crs=None) -> Path:
    """Write ``result`` (``height``, ``mask``, optional ``uncertainty``) of a map of ``geometry``
    to ``path`` atomically, as ``.npz`` (compressed) or a GeoTIFF (``.tif``/``.tiff``; see the
    module doc); returns the path. ``transform`` (points -> sensor 4x4) and ``crs`` georeference
    a GeoTIFF; an ``.npz`` stays in the sensor frame and refuses a ``crs``. A wrong suffix,
    missing or unknown arrays, shapes other than ``(geometry.size, geometry.size)``, an unknown
    CRS or a tilting transform raise ValueError before anything is written."""
    path = Path(path)
    fmt = map_format(path)
    _check_result(result, geometry)
    if fmt == "npz":
        if crs is not None:
            raise ValueError(f"crs={crs!r}: an .npz map has no coordinate reference system; write a .tif")
        arrays = {key: result[key] for key in MAP_ARRAYS if key in result}
        with atomic_open(path) as f:
            np.savez_compressed(f, **arrays, map_cell=np.float32(geometry.cell))
        return path
    return _write_geotiff(path, result, geometry, transform, crs)


def _write_geotiff(path: Path, result: Mapping, geometry: MapGeometry, transform, crs) -> Path:
    rasterio = need_rasterio()
    crs = check_crs(crs)
    affine, z_offset = map_geotransform(geometry, transform)
    height = np.asarray(result["height"], dtype=np.float64) + z_offset
    sigma = result.get("uncertainty")
    bands = np.stack([north_up(height.astype(np.float32)), north_up(np.asarray(result["mask"], dtype=np.float32)),
                      north_up(np.full(height.shape, np.nan, np.float32) if sigma is None else np.asarray(sigma, dtype=np.float32))])
    S = geometry.size
    tags = {"software": "warp-terrain reconstruct", "map_cell": repr(float(geometry.cell)), "map_size": str(S),
            "height_frame": "z in the frame the points were given in" + (" (the sensor frame)" if transform is None else ""),
            "sensor_z": repr(z_offset), "uncertainty": "none (the model predicts none)" if sigma is None else "sigma, metres"}
    if transform is not None:
        tags["points_to_sensor"] = json.dumps(np.asarray(transform, dtype=np.float64).tolist())
    with atomic_path(path) as tmp:
        with rasterio.open(tmp, "w", driver="GTiff", width=S, height=S, count=3, dtype="float32", nodata=float("nan"),
                           crs=crs, transform=rasterio.Affine(*affine), compress="deflate", predictor=3) as dst:
            dst.write(bands)
            for band, (description, unit) in enumerate(GEOTIFF_BANDS, start=1):
                dst.set_band_description(band, description)
                if unit:
                    dst.set_band_unit(band, unit)
            dst.update_tags(**tags)
    return path
