"""Real elevation rasters (DEMs) as terrain: loaded once per process, cut into random windows.

``terrain.source=dem`` takes the relief from files instead of fBm noise:

- GeoTIFF or any raster GDAL reads, through ``rasterio``; ``.las``/``.laz`` point clouds through
  ``laspy``, their ground points (class 2, else the CSF ground filter of the
  ``cloth-simulation-filter`` package) averaged into a ``ground_cell`` grid; ``.npz`` files with
  ``heights`` (2-D, metres, NaN = nodata, row 0 = north) and ``cell`` (metres), for fixtures
  made by this project. ``pip install 'warp-terrain[dem]'`` brings rasterio and laspy.
- A file must say where it is and how big its cells are: a projected CRS in metres and a north-up
  geotransform (rasters), or a CRS record (LAS/LAZ). Files without a CRS whose coordinates are
  metres in a local frame are accepted with ``assume_metres=true``. Non-square pixels are
  resampled to square ones of the finer spacing.
- Each process loads a file once (``load_dem`` is cached by path, modification time, size and
  parameters); every batch then cuts windows from memory.

A window is a square of the simulation grid (vertex ``(i, j)`` at
``x = (i - (S-1)/2) * cell``, ``y = (j - (S-1)/2) * cell``) laid on a raster at a random centre,
heading (uniform in [0, 2 pi)) and mirror (p = 0.5), at true scale unless ``scale`` says
otherwise, and sampled with a cubic spline (``scipy.ndimage.map_coordinates``, order 3, on a
NaN-free copy of the raster). Heights are relative to the ground at the window's centre vertex.
The draws of sample ``b`` come from ``(seed, first + b)`` only, like the rest of the simulator.

Nodata (the raster's nodata value, NaN, or LAS cells with no ground point): a window sample is
nodata when any raster cell its bilinear neighbourhood touches is. ``nodata="skip"`` redraws a
window when more than ``max_nodata`` of its samples are nodata (0: only complete windows);
``nodata="fill"`` keeps every window that holds some valid ground. In both, the nodata samples
of a kept window read a smooth fill of the raster's holes (a push-pull pyramid fill computed
once per file). A window made only of nodata is always redrawn; after ``tries`` draws of one
sample the batch fails with an error naming the files.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np
from scipy import ndimage

from ..core.checks import check_finite, require

NODATA_MODES = ("skip", "fill")
RASTER_INSTALL = "pip install 'warp-terrain[dem]' (rasterio)"
LAS_INSTALL = "pip install 'warp-terrain[dem]' (laspy[lazrs])"
DEM_STREAM = 0xDE3  # random stream of the window draws (the Warp kernels use their own streams)
EDGE = 1.0  # raster cells a window keeps from the raster's edge (the cubic's support)
SPLINE_MARGIN = 12  # raster cells around a window that the cubic prefilter sees (error ~0.27^12)
SMALL_HOLE_CELLS = 16  # gridded LAS: enclosed holes of at most this many cells are filled
LAS_SUFFIXES = (".las", ".laz")


@dataclass
class DemConfig:
    """Where the relief of ``terrain.source=dem`` comes from and how windows are cut from it.

    - ``files``: rasters (GeoTIFF or any GDAL raster), ``.las``/``.laz`` point clouds or
      ``.npz`` fixtures (``heights`` + ``cell``); windows pick a file weighted by its valid area.
    - ``ground_cell`` (m): grid cell that LAS/LAZ ground points are averaged into.
    - ``nodata``: ``"skip"`` redraws windows with more than ``max_nodata`` nodata samples;
      ``"fill"`` keeps them, holes filled smoothly (a window with no valid ground is redrawn).
    - ``max_nodata`` (fraction of a window's samples, in [0, 1)): the most nodata ``skip`` keeps.
    - ``scale`` (dimensionless): horizontal scale of the rasters in the simulation; 1 is true
      scale, 0.5 shrinks the ground to half its size (slopes twice as steep).
    - ``height_scale`` (dimensionless): vertical scale of the heights; set it equal to ``scale``
      to shrink a coarse raster uniformly, slopes kept (a 20 m DEM at ``scale=height_scale=0.05``
      becomes 1 m cells of the same slopes). Terrain at any scale other than 1 is not real ground
      at its real size: label it so (``label()``).
    - ``heading`` (bool): random heading uniform in [0, 2 pi) rad per window (else north-up).
    - ``mirror`` (bool): mirror each window with probability 0.5.
    - ``detrend`` (bool): subtract each window's least-squares plane (the regional slope).
    - ``tries`` (count): draws per window before giving up with an error.
    - ``assume_metres`` (bool): accept files without a CRS, taking their coordinates as metres.
    """

    files: list[str] = field(default_factory=list)
    ground_cell: float = 0.5
    nodata: str = "skip"
    max_nodata: float = 0.0
    scale: float = 1.0
    height_scale: float = 1.0
    heading: bool = True
    mirror: bool = True
    detrend: bool = False
    tries: int = 100
    assume_metres: bool = False

    def validate(self, name: str = "dem", load: bool = False) -> None:
        """Check the ranges; with ``load`` also that files are given and each loads as a DEM."""
        require(isinstance(self.files, (list, tuple)), f"{name}.files", self.files, "must be a list of paths")
        for k, path in enumerate(self.files):
            require(isinstance(path, str) and path.strip() != "", f"{name}.files[{k}]", path, "must be a non-empty path")
        for key in ("ground_cell", "max_nodata", "scale", "height_scale"):
            check_finite(f"{name}.{key}", getattr(self, key))
        require(self.ground_cell > 0, f"{name}.ground_cell", self.ground_cell, "must be > 0 (metres)")
        require(self.nodata in NODATA_MODES, f"{name}.nodata", self.nodata, f"must be one of {', '.join(NODATA_MODES)}")
        require(0.0 <= self.max_nodata < 1.0, f"{name}.max_nodata", self.max_nodata, "must be in [0, 1) (a share of the window)")
        require(self.scale > 0, f"{name}.scale", self.scale, "must be > 0 (1 = true scale)")
        require(self.height_scale > 0, f"{name}.height_scale", self.height_scale, "must be > 0 (1 = true heights)")
        for key in ("heading", "mirror", "detrend", "assume_metres"):
            require(isinstance(getattr(self, key), bool), f"{name}.{key}", getattr(self, key), "must be true or false")
        require(isinstance(self.tries, int) and not isinstance(self.tries, bool) and self.tries >= 1, f"{name}.tries", self.tries, "must be an integer >= 1")
        if load:
            require(len(self.files) > 0, f"{name}.files", list(self.files), "give at least one raster (terrain.dem.files=[a.tif,...])")
            for k, path in enumerate(self.files):
                try:
                    load_dem(path, self.ground_cell, self.assume_metres)
                except DemFileError as err:
                    raise ValueError(f"{name}.files[{k}]={path!r}: {err.reason}") from None

    def label(self) -> str:
        """``"true scale"``, or how the ground was rescaled (for names of rescaled families)."""
        if self.scale == 1.0 and self.height_scale == 1.0:
            return "true scale"
        if self.scale == self.height_scale:
            return f"rescaled x{self.scale:g} uniformly (slopes kept)"
        return f"rescaled x{self.scale:g} horizontally, x{self.height_scale:g} vertically (slopes x{self.height_scale / self.scale:.3g})"


class DemFileError(ValueError):
    """A file that cannot serve as a DEM; ``reason`` says why and what to do."""

    def __init__(self, path, reason: str):
        super().__init__(f"{path}: {reason}")
        self.path = str(path)
        self.reason = reason


@dataclass(eq=False)
class Dem:
    """A loaded elevation raster.

    ``heights``: float32 ``(rows, cols)`` metres, NaN where nodata; row 0 is the north edge and
    columns run west to east. ``cell_m``: the (square) cell size in metres. ``crs``: the CRS as
    text. ``origin``: (east, north) of cell (0, 0)'s centre in the CRS's metres.
    """

    heights: np.ndarray
    cell_m: float
    crs: str
    path: str
    origin: tuple[float, float] = (0.0, 0.0)

    @cached_property
    def valid(self) -> np.ndarray:
        """Bool mask of cells with an elevation."""
        return np.isfinite(self.heights)

    @cached_property
    def complete(self) -> bool:
        """Whether every cell has an elevation."""
        return bool(self.valid.all())

    @property
    def valid_area(self) -> float:
        """Area of the cells with an elevation, m^2."""
        return float(np.count_nonzero(self.valid)) * self.cell_m**2

    @property
    def extent(self) -> tuple[float, float]:
        """(north-south, east-west) extent in metres."""
        return self.heights.shape[0] * self.cell_m, self.heights.shape[1] * self.cell_m

    @cached_property
    def filled(self) -> np.ndarray:
        """float32 heights with the holes filled smoothly (``smooth_fill``)."""
        if self.complete:
            return self.heights
        filled = smooth_fill(self.heights)
        filled.setflags(write=False)
        return filled


# ------------------------------------------------------------------------------ filling
def smooth_fill(heights: np.ndarray) -> np.ndarray:
    """A NaN-free copy of ``heights``: valid cells unchanged, holes filled by a push-pull
    pyramid (2x2 means down to a level without holes, bilinear back up), float32."""
    valid = np.isfinite(heights)
    if not valid.any():
        raise ValueError("smooth_fill: no valid cell to fill from")
    values = np.where(valid, heights, 0.0).astype(np.float64)
    return _push_pull(values, valid.astype(np.float64)).astype(np.float32)


def _push_pull(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Normalised ``values / weights`` with zero-weight cells filled from coarser levels."""
    mean = np.divide(values, weights, out=np.zeros_like(values), where=weights > 0)
    if (weights > 0).all() or max(values.shape) <= 1:
        return mean
    rows, cols = values.shape
    padded = [np.pad(a, ((0, rows % 2), (0, cols % 2))) for a in (values, weights)]
    coarse_v, coarse_w = (a.reshape(a.shape[0] // 2, 2, a.shape[1] // 2, 2).sum(axis=(1, 3)) for a in padded)
    coarse = _push_pull(coarse_v, coarse_w)
    r = (np.arange(rows) - 0.5) / 2.0
    c = (np.arange(cols) - 0.5) / 2.0
    up = ndimage.map_coordinates(coarse, np.meshgrid(r, c, indexing="ij"), order=1, mode="nearest")
    w = np.minimum(weights, 1.0)
    return w * mean + (1.0 - w) * up


# ------------------------------------------------------------------------------ loading
def load_dem(path, ground_cell: float = 0.5, assume_metres: bool = False) -> Dem:
    """The DEM in ``path`` (raster, LAS/LAZ gridded at ``ground_cell`` m, or ``.npz``).

    Cached per process by resolved path, modification time, size and parameters: a worker
    reads each file once. Raises ``DemFileError`` (a ``ValueError`` naming the file) when the
    file cannot serve: unreadable, no CRS or cell size, degrees, rotated, no valid cell.
    """
    p = Path(os.fspath(path)).expanduser()
    try:
        resolved = p.resolve(strict=True)
        stat = resolved.stat()
    except OSError:
        raise DemFileError(path, "no such file") from None
    if not resolved.is_file():
        raise DemFileError(path, "not a file")
    las = resolved.suffix.lower() in LAS_SUFFIXES
    return _load_cached(str(resolved), stat.st_mtime_ns, stat.st_size, float(ground_cell) if las else 0.0, bool(assume_metres))


@lru_cache(maxsize=16)
def _load_cached(path: str, mtime_ns: int, size: int, ground_cell: float, assume_metres: bool) -> Dem:
    suffix = Path(path).suffix.lower()
    if suffix in LAS_SUFFIXES:
        dem = _read_las(path, ground_cell, assume_metres)
    elif suffix == ".npz":
        dem = _read_npz(path)
    else:
        dem = _read_raster(path, assume_metres)
    if not dem.valid.any():
        raise DemFileError(path, "holds no valid elevation (every cell is nodata)")
    dem.heights.setflags(write=False)
    return dem


def load_dems(cfg: DemConfig) -> list[Dem]:
    """Every file of ``cfg``, loaded (cached) in order."""
    return [load_dem(path, cfg.ground_cell, cfg.assume_metres) for path in cfg.files]


def _first_line(err: Exception) -> str:
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


def _check_crs(path: str, crs, assume_metres: bool) -> str:
    """The CRS as text if it is projected in metres; else a ``DemFileError`` saying what to do."""
    if crs is None:
        if assume_metres:
            return "none (coordinates assumed metres)"
        raise DemFileError(
            path,
            "has no CRS, so its cell size in metres is unknown: assign a projected CRS in metres "
            "(gdal_edit.py -a_srs EPSG:<code>) or, if its coordinates are metres, set terrain.dem.assume_metres=true",
        )
    text = crs.to_string() or crs.to_wkt()
    text = text if len(text) <= 60 else text[:57] + "..."
    if not crs.is_projected:
        raise DemFileError(path, f"CRS {text} is not projected (degrees): reproject it to metres, e.g. gdalwarp -t_srs EPSG:<UTM zone code>")
    try:
        units, factor = crs.linear_units_factor
    except Exception as err:  # rasterio's CRSError for CRSs without linear units
        raise DemFileError(path, f"CRS {text} has no linear unit ({_first_line(err)}): reproject it to a projected CRS in metres") from None
    if abs(float(factor) - 1.0) > 1e-9:
        raise DemFileError(path, f"CRS {text} is in {units}, not metres: reproject it to a projected CRS in metres (gdalwarp -t_srs)")
    return text


def _read_raster(path: str, assume_metres: bool) -> Dem:
    try:
        import rasterio
        from rasterio.errors import NotGeoreferencedWarning
    except ImportError:
        raise DemFileError(path, f"reading rasters needs rasterio: {RASTER_INSTALL}") from None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        try:
            src = rasterio.open(path)
        except Exception as err:
            raise DemFileError(path, f"not a readable raster ({_first_line(err)})") from None
    with src:
        t = src.transform
        if t.is_identity or not all(map(math.isfinite, (t.a, t.b, t.d, t.e))) or t.a == 0 or t.e == 0:
            raise DemFileError(path, "has no geotransform, so its cell size is unknown: georeference it (gdal_translate -a_ullr / gdal_edit.py)")
        if t.b != 0 or t.d != 0:
            raise DemFileError(path, "has a rotated geotransform: warp it north-up first (gdalwarp)")
        crs = _check_crs(path, src.crs, assume_metres)
        try:
            band = src.read(1, masked=True)
        except Exception as err:
            raise DemFileError(path, f"cannot read band 1 ({_first_line(err)})") from None
        west, north = min(t.c, t.c + t.a * src.width), max(t.f, t.f + t.e * src.height)
    heights = np.ma.filled(band.astype(np.float64), np.nan)
    heights[~np.isfinite(heights)] = np.nan
    if t.a < 0:
        heights = heights[:, ::-1]
    if t.e > 0:
        heights = heights[::-1, :]
    dx, dy = abs(t.a), abs(t.e)
    heights, cell = _square_cells(heights, dx, dy)
    return Dem(heights.astype(np.float32), cell, crs, path, (west + 0.5 * cell, north - 0.5 * cell))


def _square_cells(heights: np.ndarray, dx: float, dy: float) -> tuple[np.ndarray, float]:
    """Heights on square cells of ``min(dx, dy)`` (bilinear; a sample touching nodata is nodata)."""
    if abs(dx - dy) <= 1e-6 * max(dx, dy):
        return heights, float(dx)
    cell = min(dx, dy)
    rows = int(math.floor((heights.shape[0] - 1) * dy / cell + 1e-9)) + 1
    cols = int(math.floor((heights.shape[1] - 1) * dx / cell + 1e-9)) + 1
    coords = np.meshgrid(np.arange(rows) * cell / dy, np.arange(cols) * cell / dx, indexing="ij")
    return ndimage.map_coordinates(heights, coords, order=1, mode="nearest", cval=np.nan), float(cell)


def _read_npz(path: str) -> Dem:
    try:
        with np.load(path, allow_pickle=False) as data:
            heights = np.asarray(data["heights"], dtype=np.float64)
            cell = float(np.asarray(data["cell"]))
    except Exception as err:
        raise DemFileError(path, f"not a DEM .npz with 'heights' and 'cell' ({_first_line(err)})") from None
    if heights.ndim != 2 or min(heights.shape) < 2:
        raise DemFileError(path, f"'heights' must be 2-D with at least 2 x 2 cells, got shape {heights.shape}")
    if not (math.isfinite(cell) and cell > 0):
        raise DemFileError(path, f"'cell' must be a positive cell size in metres, got {cell!r}")
    heights[~np.isfinite(heights)] = np.nan
    return Dem(heights.astype(np.float32), cell, "none (.npz, metres)", path)


# ------------------------------------------------------------------------------ LAS / LAZ
def _read_las(path: str, ground_cell: float, assume_metres: bool) -> Dem:
    try:
        import laspy
    except ImportError:
        raise DemFileError(path, f"reading LAS/LAZ needs laspy: {LAS_INSTALL}") from None
    try:
        las = laspy.read(path)
    except Exception as err:
        raise DemFileError(path, f"not a readable LAS/LAZ file ({_first_line(err)})") from None
    crs = _check_crs(path, _las_crs(path, las), assume_metres)
    if len(las.points) == 0:
        raise DemFileError(path, "holds no points")
    xyz = np.column_stack([np.asarray(las.x, dtype=np.float64), np.asarray(las.y, dtype=np.float64), np.asarray(las.z, dtype=np.float64)])
    ground = np.asarray(las.classification) == 2
    if not ground.any():
        ground = _csf_ground(path, xyz, ground_cell)
    heights, origin = grid_points(xyz[ground], ground_cell)
    return Dem(heights.astype(np.float32), float(ground_cell), crs, path, origin)


def _las_crs(path: str, las):
    """The rasterio CRS of a LAS file's WKT or GeoKey record, or None."""
    from laspy.vlrs.known import GeoKeyDirectoryVlr, WktCoordinateSystemVlr

    records = list(las.header.vlrs) + list(getattr(las, "evlrs", None) or [])
    wkt = next((r for r in records if isinstance(r, WktCoordinateSystemVlr)), None)
    keys = next((r for r in records if isinstance(r, GeoKeyDirectoryVlr)), None)
    if wkt is None and keys is None:
        return None
    try:
        from rasterio.crs import CRS
    except ImportError:
        raise DemFileError(path, f"reading a LAS file's CRS needs rasterio: {RASTER_INSTALL}") from None
    try:
        if wkt is not None and wkt.string.strip("\x00 "):
            return CRS.from_wkt(wkt.string.strip("\x00 "))
        codes = {key.id: key.value_offset for key in keys.geo_keys}
        for key_id in (3072, 2048):  # ProjectedCSTypeGeoKey, then GeographicTypeGeoKey
            if 1024 <= codes.get(key_id, 0) <= 32766:
                return CRS.from_epsg(codes[key_id])
    except Exception as err:
        raise DemFileError(path, f"has a CRS record that cannot be read ({_first_line(err)}): rewrite it with an EPSG code") from None
    raise DemFileError(path, "has a user-defined CRS record without an EPSG code: rewrite it with an EPSG code (e.g. pdal translate --writers.las.a_srs)")


def _csf_ground(path: str, xyz: np.ndarray, ground_cell: float) -> np.ndarray:
    """Ground mask of an unclassified cloud from the cloth-simulation filter (CSF)."""
    try:
        import CSF
    except ImportError:
        raise DemFileError(
            path,
            "has no ground-classified points (class 2) and the CSF ground filter is not installed: "
            "pip install cloth-simulation-filter, or classify ground first (e.g. PDAL filters.csf / filters.smrf)",
        ) from None
    csf = CSF.CSF()
    csf.params.bSloopSmooth = True
    csf.params.cloth_resolution = float(ground_cell)
    csf.setPointCloud(xyz - xyz.min(axis=0))  # CSF computes in float: keep the numbers small
    ground, rest = CSF.VecInt(), CSF.VecInt()
    csf.do_filtering(ground, rest, False)
    mask = np.zeros(len(xyz), dtype=bool)
    mask[np.asarray(ground, dtype=np.int64)] = True
    if not mask.any():
        raise DemFileError(path, "the CSF ground filter found no ground points: classify ground first (class 2)")
    return mask


def grid_points(xyz: np.ndarray, cell: float) -> tuple[np.ndarray, tuple[float, float]]:
    """Mean height of the points in each ``cell`` m square, north-up, and the (east, north) of
    cell (0, 0)'s centre. Cells on the grid's multiples of ``cell``; enclosed holes of at most
    ``SMALL_HOLE_CELLS`` cells are filled smoothly, larger gaps stay NaN (nodata)."""
    west = math.floor(xyz[:, 0].min() / cell) * cell
    top = (math.floor(xyz[:, 1].max() / cell) + 1) * cell
    col = np.floor((xyz[:, 0] - west) / cell).astype(np.int64)
    row = np.floor((top - xyz[:, 1]) / cell).astype(np.int64)
    rows, cols = int(row.max()) + 1, int(col.max()) + 1
    index = row * cols + col
    sums = np.bincount(index, weights=xyz[:, 2], minlength=rows * cols)
    counts = np.bincount(index, minlength=rows * cols)
    heights = np.divide(sums, counts, out=np.full(rows * cols, np.nan), where=counts > 0).reshape(rows, cols)
    holes, n = ndimage.label(np.isnan(heights))
    if n:
        sizes = np.bincount(holes.ravel(), minlength=n + 1)
        border = np.unique(np.concatenate([holes[0], holes[-1], holes[:, 0], holes[:, -1]]))
        small = sizes <= SMALL_HOLE_CELLS
        small[0] = False
        small[border] = False
        fill = small[holes]
        if fill.any():
            heights[fill] = smooth_fill(heights)[fill]
    return heights, (west + 0.5 * cell, top - 0.5 * cell)


# ------------------------------------------------------------------------------ windows
@dataclass(frozen=True)
class WindowDraw:
    """Where one window was cut: ``raster`` (index into the DEMs), its centre (``row``, ``col``;
    fractional raster cells), ``heading`` (rad; sim x axis towards east at 0, counter-clockwise),
    ``mirror`` (sim y negated before the rotation), ``nodata`` (share of nodata samples), and
    ``draws`` (how many draws it took)."""

    raster: int
    row: float
    col: float
    heading: float
    mirror: bool
    nodata: float
    draws: int


def window_reach(size: int, cell: float, dem: Dem, cfg: DemConfig, heading: float | None) -> float:
    """Half the side, in raster cells, of the axis-aligned box a window covers on ``dem``
    (``heading=None``: the largest over every heading the config allows)."""
    half = 0.5 * (size - 1) * cell / cfg.scale / dem.cell_m
    if heading is None:
        return half * (math.sqrt(2.0) if cfg.heading else 1.0)
    return half * (abs(math.cos(heading)) + abs(math.sin(heading)))


def check_fit(dems: list[Dem], size: int, cell: float, cfg: DemConfig) -> None:
    """Every raster must hold a window of ``size`` vertices at ``cell`` m, at any heading."""
    for k, dem in enumerate(dems):
        need = 2.0 * (window_reach(size, cell, dem, cfg, None) + EDGE) + 1.0
        if min(dem.heights.shape) < need:
            rows, cols = dem.heights.shape
            side = (size - 1) * cell
            raise ValueError(
                f"terrain.dem.files[{k}]={dem.path!r}: {rows} x {cols} cells of {dem.cell_m:g} m is too small for a "
                f"{side:g} m window (the map plus its margin{', at any heading' if cfg.heading else ''}"
                f"{'' if cfg.scale == 1 else f', scale {cfg.scale:g}'}): it needs at least {math.ceil(need)} x {math.ceil(need)} cells"
            )


def _crop(array: np.ndarray, coords: np.ndarray, margin: int, odd: bool) -> tuple[np.ndarray, np.ndarray]:
    """The part of ``array`` around ``coords`` (plus ``margin`` cells, padded beyond the array's
    edge: odd reflection, which continues slopes, or zeros) and ``coords`` relative to it."""
    lo = np.floor(coords.reshape(2, -1).min(axis=1)).astype(int) - margin
    hi = np.ceil(coords.reshape(2, -1).max(axis=1)).astype(int) + margin + 1
    shape = np.array(array.shape)
    a, b = np.maximum(lo, 0), np.minimum(hi, shape)
    part = np.array(array[a[0]:b[0], a[1]:b[1]], dtype=np.float64)  # a copy: the raster stays as loaded
    pad = [(int(a[i] - lo[i]), int(hi[i] - b[i])) for i in range(2)]
    if any(p for pair in pad for p in pair):
        part = np.pad(part, pad, mode="reflect", reflect_type="odd") if odd else np.pad(part, pad)
    return part, coords - lo.reshape(2, 1, 1)


def _window_coords(size: int, cell: float, dem: Dem, cfg: DemConfig, row: float, col: float, heading: float, mirror: bool) -> np.ndarray:
    """``(2, size, size)`` fractional raster (row, col) of the window's vertices."""
    offsets = (np.arange(size) - 0.5 * (size - 1)) * (cell / cfg.scale / dem.cell_m)
    x, y = np.meshgrid(offsets, -offsets if mirror else offsets, indexing="ij")
    east = math.cos(heading) * x - math.sin(heading) * y
    north = math.sin(heading) * x + math.cos(heading) * y
    return np.stack([row - north, col + east])


def _nodata_share(dem: Dem, coords: np.ndarray) -> float:
    if dem.complete:
        return 0.0
    valid, local = _crop(dem.valid, coords, 2, odd=False)
    inside = ndimage.map_coordinates(valid, local, order=1, mode="constant", cval=0.0)
    return float(np.mean(inside < 1.0 - 1e-6))


def _sample(dem: Dem, coords: np.ndarray) -> np.ndarray:
    """Cubic-spline heights at ``coords`` (float64), relative to the raster cell nearest the centre."""
    part, local = _crop(dem.filled, coords, SPLINE_MARGIN, odd=True)
    centre = tuple(int(round(v)) for v in local[:, local.shape[1] // 2, local.shape[2] // 2])
    part -= part[centre]  # small numbers: float32 keeps millimetres on mountains
    return ndimage.map_coordinates(part, local, order=3, mode="nearest")


def _detrend(heights: np.ndarray) -> np.ndarray:
    size = heights.shape[0]
    i, j = np.meshgrid(np.arange(size, dtype=np.float64), np.arange(size, dtype=np.float64), indexing="ij")
    basis = np.column_stack([i.ravel(), j.ravel(), np.ones(i.size)])
    coef, *_ = np.linalg.lstsq(basis, heights.ravel(), rcond=None)
    return heights - (basis @ coef).reshape(heights.shape)


def _one_window(dems: list[Dem], weights: np.ndarray, size: int, cell: float, cfg: DemConfig, rng: np.random.Generator):
    for attempt in range(1, cfg.tries + 1):
        k = int(rng.choice(len(dems), p=weights))
        dem = dems[k]
        heading = float(rng.uniform(0.0, 2.0 * math.pi)) if cfg.heading else 0.0
        mirror = bool(rng.integers(2)) if cfg.mirror else False
        reach = window_reach(size, cell, dem, cfg, heading) + EDGE
        rows, cols = dem.heights.shape
        row = float(rng.uniform(reach, rows - 1 - reach))
        col = float(rng.uniform(reach, cols - 1 - reach))
        coords = _window_coords(size, cell, dem, cfg, row, col, heading, mirror)
        share = _nodata_share(dem, coords)
        if share >= 1.0 or (cfg.nodata == "skip" and share > cfg.max_nodata):
            continue
        heights = _sample(dem, coords)
        if cfg.detrend:
            heights = _detrend(heights)
        heights -= heights[size // 2, size // 2]  # the ground under the sensor at z = 0
        return heights, WindowDraw(k, row, col, heading, mirror, share, attempt)
    files = ", ".join(repr(d.path) for d in dems)
    valid = ", ".join(f"{float(np.mean(d.valid)):.0%}" for d in dems)
    rule = f"at most {cfg.max_nodata:.0%} nodata" if cfg.nodata == "skip" else "any valid ground"
    raise ValueError(
        f"terrain.dem.files={files}: no window with {rule} in {cfg.tries} draws (valid share of the rasters: {valid}); "
        "raise terrain.dem.max_nodata or terrain.dem.tries, use terrain.dem.nodata=fill, or give rasters with less nodata"
    )


def dem_windows(
    dems: list[Dem], count: int, size: int, cell: float, seed: int, cfg: DemConfig, first: int = 0, draws: list | None = None
) -> np.ndarray:
    """``(count, size, size)`` float32 heights (metres) of random windows of ``dems``.

    Vertex ``(i, j)`` lies at ``x = (i - (size-1)/2) * cell``, ``y = (j - (size-1)/2) * cell``;
    heights are relative to the window's centre vertex. Sample ``b`` is drawn from
    ``(seed, first + b)`` only: a raster weighted by its valid area, a heading, a mirror and a
    centre where the rotated window fits (see the module's docstring for nodata). ``draws``, a
    list, receives each window's ``WindowDraw``.
    """
    require(len(dems) > 0, "terrain.dem.files", [], "give at least one raster")
    check_fit(dems, size, cell, cfg)
    if cfg.scale != 1.0 or cfg.height_scale != 1.0:
        warnings.warn(f"terrain.dem.scale={cfg.scale:g}, height_scale={cfg.height_scale:g}: the ground is {cfg.label()}, not true scale", stacklevel=2)
    areas = np.array([d.valid_area for d in dems], dtype=np.float64)
    weights = areas / areas.sum()
    out = np.empty((count, size, size), dtype=np.float32)
    for b in range(count):
        rng = np.random.default_rng([int(seed) & 0x7FFFFFFF, DEM_STREAM, int(first) + b])
        heights, draw = _one_window(dems, weights, size, cell, cfg, rng)
        out[b] = heights if cfg.height_scale == 1.0 else heights * np.float32(cfg.height_scale)
        if draws is not None:
            draws.append(draw)
    return out
