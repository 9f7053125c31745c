"""Terrain synthesis: fBm Perlin or real-DEM heightfields with obstacles, batched on the device."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np
import torch
import warp as wp

from ..core.checks import check_finite, require
from ..kernels import noise as noise_kernels
from ..kernels import obstacles as obstacle_kernels
from . import arena
from .arena import Seed, as_seed
from .clutter import ClutterConfig
from .dem import DemConfig, dem_windows, load_dems
from .device import resolve_device, torch_stream
from .landforms import LandformConfig, ReliefConfig, TiltConfig, add_landforms, landform_scratch_bytes
from .switches import kernel_switches
from .threads import run_parts, split_threads


@dataclass
class ObstacleConfig:
    """How many obstacles of one kind each terrain gets, and their sizes (metres).

    ``width`` is the diameter of round shapes (cylinder, rock, pit) and the width of boxes and
    ditches; ``length`` is the long side of boxes and ditches; ``height`` is the height above the
    local ground of cylinders, boxes and rocks and the depth of pits and ditches.
    """

    count_min: int = 0
    count_max: int = 0
    width_min: float = 0.5
    width_max: float = 1.5
    length_min: float = 2.0
    length_max: float = 6.0
    height_min: float = 0.5
    height_max: float = 2.0

    def validate(self, name: str) -> None:
        require(self.count_min >= 0, f"{name}.count_min", self.count_min, "must be >= 0")
        require(self.count_max >= self.count_min, f"{name}.count_max", self.count_max, "must be >= count_min")
        for key in ("width", "length", "height"):
            lo, hi = getattr(self, f"{key}_min"), getattr(self, f"{key}_max")
            check_finite(f"{name}.{key}_min", lo)
            check_finite(f"{name}.{key}_max", hi)
            require(lo > 0, f"{name}.{key}_min", lo, "must be > 0")
            require(hi >= lo, f"{name}.{key}_max", hi, f"must be >= {key}_min")


TERRAIN_SOURCES = ("fbm", "dem")

OBSTACLE_KINDS = {
    "cylinders": obstacle_kernels.CYLINDER,
    "boxes": obstacle_kernels.BOX,
    "rocks": obstacle_kernels.ROCK,
    "pits": obstacle_kernels.PIT,
    "ditches": obstacle_kernels.DITCH,
}


@dataclass
class TerrainConfig:
    """A random terrain: fBm Perlin relief (``source="fbm"``) or windows of real elevation
    rasters (``source="dem"``, files and window draws in ``dem``: ``sim/dem.py``), plus obstacles.

    The defaults are the ``octave5`` preset (``sim.presets``). The relief is ``amplitude * fBm`` with ``octaves`` octaves whose first wavelength is
    ``feature_size`` metres (each octave ``lacunarity`` times finer and ``persistence`` times
    weaker); heights lie within +-``amplitude``. ``cell`` is the terrain's resolution, finer
    than the elevation map so obstacle edges stay sharp; ``margin`` is how far the terrain
    extends beyond the map on each side, so shadows near the map's edge come from real terrain.
    Obstacles are placed in the square ``+-obstacle_region`` metres around the sensor
    (0: the map's extent), keeping ``keep_out`` metres clear around the sensor (the vehicle).
    With ``source="dem"`` the fBm keys are not used (still checked) and the obstacles stand on
    the real ground. ``tilt``, ``relief`` and ``landforms`` (``sim/landforms.py``, off by
    default) add a planar tilt, low-frequency relief, terraces, depressions and gullies to the
    fBm (not to DEM windows), before the obstacles.
    """

    name: str = "octave5"
    source: str = "fbm"
    octaves: int = 5
    persistence: float = 0.5
    lacunarity: float = 2.0
    feature_size: float = 20.0
    amplitude: float = 2.0
    cell: float = 0.125
    margin: float = 1.0
    obstacle_region: float = 0.0
    keep_out: float = 2.5
    cylinders: ObstacleConfig = field(default_factory=ObstacleConfig)
    boxes: ObstacleConfig = field(default_factory=ObstacleConfig)
    rocks: ObstacleConfig = field(default_factory=ObstacleConfig)
    pits: ObstacleConfig = field(default_factory=ObstacleConfig)
    ditches: ObstacleConfig = field(default_factory=ObstacleConfig)
    dem: DemConfig = field(default_factory=DemConfig)
    tilt: TiltConfig = field(default_factory=TiltConfig)  # planar tilt (sim/landforms.py)
    relief: ReliefConfig = field(default_factory=ReliefConfig)  # low-frequency relief
    landforms: LandformConfig = field(default_factory=LandformConfig)  # depressions, gullies, terraces
    clutter: ClutterConfig = field(default_factory=ClutterConfig)  # bushes, grass, tree crowns (sim/clutter.py)

    def validate(self, files: bool = True) -> None:
        """Check every key; with ``source="dem"`` and ``files``, also that each DEM file loads
        (``files=False`` checks a recorded config where the files may be absent)."""
        require(isinstance(self.name, str) and self.name.strip() != "", "name", self.name, "must be a non-empty label")
        require(self.source in TERRAIN_SOURCES, "source", self.source, f"must be one of {', '.join(TERRAIN_SOURCES)}")
        require(isinstance(self.octaves, int) and self.octaves >= 1, "octaves", self.octaves, "must be an integer >= 1")
        require(self.octaves <= 16, "octaves", self.octaves, "must be <= 16")
        for key in ("persistence", "lacunarity", "feature_size", "amplitude", "cell", "margin", "obstacle_region", "keep_out"):
            check_finite(key, getattr(self, key))
        require(self.persistence > 0, "persistence", self.persistence, "must be > 0")
        require(self.lacunarity > 0, "lacunarity", self.lacunarity, "must be > 0")
        require(self.feature_size > 0, "feature_size", self.feature_size, "must be > 0")
        require(self.amplitude >= 0, "amplitude", self.amplitude, "must be >= 0")
        require(self.cell > 0, "cell", self.cell, "must be > 0")
        require(self.margin >= 0, "margin", self.margin, "must be >= 0")
        require(self.obstacle_region >= 0, "obstacle_region", self.obstacle_region, "must be >= 0")
        require(self.keep_out >= 0, "keep_out", self.keep_out, "must be >= 0")
        for name in OBSTACLE_KINDS:
            getattr(self, name).validate(name)
        self.dem.validate("dem", load=files and self.source == "dem")
        self.tilt.validate("tilt")
        self.relief.validate("relief")
        self.landforms.validate("landforms")
        self.clutter.validate("clutter")

    def has_obstacles(self) -> bool:
        return any(getattr(self, name).count_max > 0 for name in OBSTACLE_KINDS)


def grid_size(extent: float, cell: float) -> int:
    """Odd number of vertices covering ``[-extent/2, extent/2]`` at ``cell`` spacing.

    Odd, so the sensor (at the centre) sits on a vertex.
    """
    return 2 * math.ceil(0.5 * extent / cell - 1e-6) + 1


def _specs(cfg: TerrainConfig, device: str):
    specs, slot_spec, slot_rank = [], [], []
    for name, kind in OBSTACLE_KINDS.items():
        oc: ObstacleConfig = getattr(cfg, name)
        if oc.count_max == 0:
            continue
        spec = obstacle_kernels.ObstacleSpec()
        spec.kind = kind
        for f in fields(oc):
            setattr(spec, f.name, getattr(oc, f.name))
        slot_spec += [len(specs)] * oc.count_max
        slot_rank += list(range(oc.count_max))
        specs.append(spec)
    return (
        arena.upload(specs, obstacle_kernels.ObstacleSpec, device),
        arena.upload(np.array(slot_spec, dtype=np.int32), int, device),
        arena.upload(np.array(slot_rank, dtype=np.int32), int, device),
    )


def scratch_bytes(cfg: TerrainConfig) -> int:
    """Transient bytes per sample ``make_heightfields`` allocates besides the heights: the
    obstacle slots and the landform draws (``sim/memory.py`` counts them)."""
    slots = sum(getattr(cfg, name).count_max for name in OBSTACLE_KINDS)
    return slots * wp.types.type_size_in_bytes(obstacle_kernels.Obstacle) + landform_scratch_bytes(cfg.relief, cfg.landforms)


def per_sample(value, batch: int, name: str) -> np.ndarray:
    """A per-sample float32 host array from a scalar or a length-``batch`` sequence / tensor."""
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().numpy()
    arr = np.broadcast_to(np.asarray(value, dtype=np.float32), (batch,))
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: must be finite, got {value!r}")
    return np.ascontiguousarray(arr)


THREAD_MIN_SAMPLES = 4  # fields per CPU thread below which splitting a batch does not pay (121^2: ~1 ms each)
TABLE_MIN_SPACING = 2.0  # vertices per lattice cell below which an octave reads wp.noise directly


def fbm_rows(fields_: wp.array, offsets: wp.array, cfg: TerrainConfig, features: wp.array, feature_min: float, amplitudes: wp.array,
             heights: wp.array) -> None:
    """The lattice-gradient fBm (``kernels/noise.py``; the CPU's path, on CUDA behind the
    ``fbm_table`` switch): lattice gradients read once, then one thread per row of vertices.
    Octaves whose lattice cells span fewer than ``TABLE_MIN_SPACING`` vertices (no reuse to
    gain) call ``wp.noise`` directly. ``feature_min`` (metres, known on the host: no device
    read) is the smallest of ``features``; it sizes the gradient tables."""
    batch, rows, columns = heights.shape
    device = heights.device
    frequencies = [cfg.lacunarity**o for o in range(cfg.octaves)]
    table = 0
    while table < cfg.octaves and feature_min / (frequencies[table] * cfg.cell) >= TABLE_MIN_SPACING:
        table += 1
    if table:
        span = (max(rows, columns) - 1) * cfg.cell / feature_min * max(frequencies[:table])
        n = math.ceil(span) + 4  # one cell below the grid, the far corner, and rounding
        gradients = arena.empty((batch, table, n, n), wp.vec2, device)
        origin = arena.empty((batch, table), wp.vec2i, device)
        wp.launch(
            noise_kernels.lattice_gradients,
            dim=gradients.shape[:3],  # one thread per table row
            inputs=[fields_, offsets, cfg.cell, cfg.lacunarity, features, rows, columns],
            outputs=[origin, gradients],
            device=device,
        )
    else:  # every octave reads wp.noise; the kernel still takes (unused) arrays
        gradients = arena.zeros((batch, 1, 2, 2), wp.vec2, device)
        origin = arena.zeros((batch, 1), wp.vec2i, device)
    wp.launch(
        noise_kernels.fractal_rows,
        dim=(batch, rows),
        inputs=[fields_, offsets, gradients, origin, table, cfg.cell, cfg.persistence, cfg.lacunarity, features, amplitudes],
        outputs=[heights],
        device=device,
    )


def make_heightfields(
    batch: int,
    size: int,
    cfg: TerrainConfig,
    seed,
    device: str,
    feature_size=None,
    amplitude=None,
    obstacle_region: float | None = None,
    first: int = 0,
    out: wp.array | None = None,
) -> wp.array:
    """``(batch, size, size)`` Warp heightfields: the relief (fBm with the configured
    landforms, or DEM windows with ``cfg.source="dem"``), then obstacles stamped in.

    ``feature_size`` / ``amplitude`` override the config per sample (domain randomisation; fBm
    only). Samples are numbered from ``first`` (sample ``first + b`` is the same terrain in any
    batch, so processes can split a batch: ``sim/parallel.py``); ``out`` receives them if given.
    """
    cell = cfg.cell
    seed = as_seed(seed, device)
    heights = out if out is not None else arena.empty((batch, size, size), float, device)
    if cfg.source == "dem":
        windows = dem_windows(load_dems(cfg.dem), batch, size, cell, seed.value, cfg.dem, first=int(first))
        wp.copy(heights, wp.array(windows, dtype=float, device=device))
    else:
        _fbm_relief(heights, cfg, seed, device, feature_size, amplitude, first)
        add_landforms(heights, cell, cfg.tilt, cfg.relief, cfg.landforms, seed, device, int(first))
    if cfg.has_obstacles():
        specs, slot_spec, slot_rank = _specs(cfg, device)
        region = obstacle_region if obstacle_region is not None else cfg.obstacle_region
        if region <= 0:
            region = 0.5 * (size - 1) * cell
        obstacles = arena.empty((batch, slot_spec.shape[0]), obstacle_kernels.Obstacle, device)
        wp.launch(
            obstacle_kernels.sample_obstacles,
            dim=obstacles.shape,
            inputs=[seed.array, int(first), specs, slot_spec, slot_rank, heights, cell, float(region), cfg.keep_out],
            outputs=[obstacles],
            device=device,
        )
        wp.launch(obstacle_kernels.stamp_obstacles, dim=heights.shape, inputs=[obstacles, cell], outputs=[heights], device=device)
    return heights


def _fbm_relief(heights: wp.array, cfg: TerrainConfig, seed: Seed, device: str, feature_size, amplitude, first: int) -> None:
    """Write ``amplitude * fBm`` into ``heights`` (per-sample ``feature_size``/``amplitude`` if given)."""
    batch = heights.shape[0]
    fields_ = arena.empty((batch, cfg.octaves), wp.uint32, device)
    offsets = arena.empty((batch, cfg.octaves), wp.vec2, device)
    wp.launch(noise_kernels.octave_fields, dim=(batch, cfg.octaves), inputs=[seed.array, int(first)], outputs=[fields_, offsets], device=device)
    features = per_sample(cfg.feature_size if feature_size is None else feature_size, batch, "feature_size")
    feature_min = float(features.min())
    features = arena.upload(features, float, device)
    amplitudes = arena.upload(per_sample(cfg.amplitude if amplitude is None else amplitude, batch, "amplitude"), float, device)
    if kernel_switches().fbm_table_on(device):
        fbm_rows(fields_, offsets, cfg, features, feature_min, amplitudes, heights)
    else:
        wp.launch(
            noise_kernels.fractal_heightfield,
            dim=heights.shape,
            inputs=[fields_, offsets, cfg.cell, cfg.persistence, cfg.lacunarity, features, amplitudes],
            outputs=[heights],
            device=device,
        )


def fractal_heightfield(
    batch: int,
    size: int,
    cell: float,
    octaves: int = 5,
    persistence: float = 0.5,
    lacunarity: float = 2.0,
    feature_size: float = 8.0,
    amplitude: float = 1.0,
    seed: int = 0,
    device=None,
    threads: int | None = None,
) -> torch.Tensor:
    """``(batch, size, size)`` float32 fBm Perlin heights in metres, one launch for the batch.

    Vertex (i, j) lies at ``x = (i - (size-1)/2) * cell``, ``y = (j - (size-1)/2) * cell``.
    ``feature_size`` is the first octave's wavelength (metres); heights lie within
    ``+-amplitude`` metres. Sample ``b`` depends only on ``(seed, b)``, not on ``batch``, so on
    the CPU the batch is split over ``threads`` (``None``: every usable core, where each gets at
    least ``THREAD_MIN_SAMPLES`` maps; ``sim/threads.py``) with the same heights, bit for bit.
    """
    require(isinstance(batch, (int, np.integer)) and batch >= 1, "batch", batch, "must be an integer >= 1")
    require(isinstance(size, (int, np.integer)) and size >= 2, "size", size, "must be an integer >= 2")
    cfg = TerrainConfig(
        octaves=octaves,
        persistence=persistence,
        lacunarity=lacunarity,
        feature_size=feature_size,
        amplitude=amplitude,
        cell=cell,
    )
    cfg.validate()
    device = resolve_device(device)
    batch, size = int(batch), int(size)
    threads = split_threads(threads, batch, THREAD_MIN_SAMPLES, device)
    heights = wp.empty((batch, size, size), dtype=float, device=device)
    parts = [range(k * batch // threads, (k + 1) * batch // threads) for k in range(threads)]
    if threads > 1:
        for module in ("noise", "landforms", "obstacles"):  # compile/load once, not from several threads
            wp.load_module(f"warp_terrain.kernels.{module}", device=device)

    def fill(part: range) -> None:
        make_heightfields(len(part), size, cfg, int(seed), device, first=part.start, out=heights[part.start:part.stop])

    with torch_stream(device):
        run_parts(fill, parts)
    return wp.to_torch(heights)
