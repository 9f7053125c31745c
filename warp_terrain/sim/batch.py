"""Training pairs: terrain -> LIDAR scan -> projected scan image, and the true elevation map.

Everything for a batch happens in a handful of Warp launches on one device; the results are
handed to torch with ``wp.to_torch``, sharing memory with the Warp arrays (no copies).
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass, field

import torch
import warp as wp

from ..core.checks import check_finite, require
from ..core.geometry import MAP_CELL, MAP_SIZE, MapGeometry
from ..core.structs import build
from ..kernels import clutter as clutter_kernels
from ..kernels import ground_truth as truth_kernels
from ..kernels import projection as projection_kernels
from . import arena
from .arena import Seed, as_seed
from .clutter import CanopyLayer, make_canopy
from .dem import check_fit, load_dems
from .device import resolve_device, to_warp, torch_stream
from .lidar import LidarConfig, lidar_preset
from .memory import check_batch_fits
from .projection import bin_into_maps, check_map
from .randomize import RandomizeConfig, randomize
from .scan import as_heightfields, trace
from .terrain import TerrainConfig, grid_size, make_heightfields, scratch_bytes


@dataclass
class DataConfig:
    """The elevation maps and what is done to them.

    ``map_size x map_size`` cells of ``map_cell`` metres centred on the sensor (the paper: 121,
    at 0.25 m here: a 30 m square). ``noise`` is the paper's "x% noise": Gaussian noise of
    ``noise`` times the sample's height range added to observed cells of the scan image.
    ``augment`` applies a random flip / 90-degree rotation per sample (to points, scan and
    target alike). ``truth_samples``^2 surface samples average into each ground-truth cell.
    ``fill`` is the scan image's value where no point landed (the mask tells those cells).
    ``clip_rays`` stops every ray where it leaves the map's square: what lies beyond cannot
    enter the images, so it is not cast (``Batch.points`` then holds the returns within the
    map); set it false for the whole scan over the whole simulated terrain.
    """

    map_size: int = MAP_SIZE
    map_cell: float = MAP_CELL
    noise: float = 0.0
    augment: bool = True
    truth_samples: int = 4
    fill: float = 0.0
    clip_rays: bool = True
    randomize: RandomizeConfig = field(default_factory=RandomizeConfig)

    @property
    def geometry(self) -> MapGeometry:
        """The map's size, cell, extent and cell centres."""
        return MapGeometry(self.map_size, self.map_cell)

    def validate(self) -> None:
        check_map(self.map_size, self.map_cell)
        self.randomize.validate()
        check_finite("noise", self.noise)
        require(0.0 <= self.noise <= 1.0, "noise", self.noise, "must be in [0, 1] (a fraction of the height range)")
        require(isinstance(self.truth_samples, int) and self.truth_samples >= 1, "truth_samples", self.truth_samples, "must be an integer >= 1")
        check_finite("fill", self.fill)


@dataclass
class SimConfig:
    """Everything ``generate_batch`` needs: the terrain, the sensor and the maps."""

    terrain: TerrainConfig = field(default_factory=TerrainConfig)
    lidar: LidarConfig = field(default_factory=lambda: lidar_preset("hdl32e"))
    data: DataConfig = field(default_factory=DataConfig)

    def validate(self, files: bool = True) -> None:
        """Check every section; ``files=False`` skips loading DEM files (``terrain.source=dem``),
        for a recorded config (a checkpoint's, a dataset's) used where they may be absent."""
        self.terrain.validate(files)
        self.lidar.validate()
        self.data.validate()
        mixes_dem = self.data.randomize.enabled and self.data.randomize.dem_probability > 0
        require(not mixes_dem or bool(self.terrain.dem.files), "data.randomize.dem_probability",
                self.data.randomize.dem_probability, "mixes in real ground: name the rasters in terrain.dem.files")
        if files and (self.terrain.source == "dem" or mixes_dem):  # every raster must hold a window of the map plus its margin
            check_fit(load_dems(self.terrain.dem), terrain_size(self), self.terrain.cell, self.terrain.dem)


@dataclass
class Batch:
    """A batch of training pairs, torch tensors sharing memory with the Warp arrays.

    - ``scan``:   ``(B, 1, S, S)`` mean height of the LIDAR points in each cell (sensor frame,
      metres; ``fill`` where none), with image noise if configured: the network's input
    - ``mask``:   ``(B, 1, S, S)`` 1.0 where at least one point landed
    - ``target``: ``(B, 1, S, S)`` the true surface averaged over each cell (sensor frame)
    - ``points``: ``(B, rays, 3)`` the scans in each sensor frame, NaN rows for no return
    - ``scan_max``: ``(B, 1, S, S)`` highest point per cell (``fill`` where none)
    - ``heights``: ``(B, H, W)`` the simulated terrains (world heights, terrain cell spacing)
    - ``sensor_z``: ``(B,)`` each sensor's world height
    - ``target_visible``: ``(B, 1, S, S)`` with clutter on (``terrain.clutter``, else None):
      the highest surface the LIDAR could see from above (ground or canopy top) averaged over
      each cell like ``target``, which stays the bare ground
    """

    scan: torch.Tensor
    mask: torch.Tensor
    target: torch.Tensor
    points: torch.Tensor
    scan_max: torch.Tensor
    heights: torch.Tensor
    sensor_z: torch.Tensor
    target_visible: torch.Tensor | None = None
    warp_arrays: dict = field(default_factory=dict, repr=False)

    def to(self, device) -> Batch:
        moved = {k: getattr(self, k).to(device) for k in ("scan", "mask", "target", "points", "scan_max", "heights", "sensor_z")}
        if self.target_visible is not None:
            moved["target_visible"] = self.target_visible.to(device)
        return Batch(**moved)


def as_sim_config(cfg, files: bool = True) -> SimConfig:
    """A validated ``SimConfig`` from None, a ``SimConfig``/``DataConfig``, or any object or
    mapping (a Hydra run config, a ``RunConfig``, a checkpoint's config dict) with
    ``terrain``/``lidar``/``data`` entries; what they give is merged over the defaults.
    ``files=False``: DEM files are not loaded (see ``SimConfig.validate``)."""
    if cfg is None:
        sim = SimConfig()
    elif isinstance(cfg, SimConfig):
        sim = cfg
    elif isinstance(cfg, DataConfig):
        sim = SimConfig(data=cfg)
    else:
        sections = ("terrain", "lidar", "data")
        if dataclasses.is_dataclass(cfg):
            picked = {k: getattr(cfg, k) for k in sections if hasattr(cfg, k)}
        else:
            picked = {k: cfg[k] for k in sections if k in cfg}
        sim = build(SimConfig, picked)
    sim.validate(files)
    return sim


def unaugmented(sim: SimConfig) -> SimConfig:
    """A validated copy of ``sim`` whose points and maps keep the terrain's orientation: no
    augmentation, no domain randomisation (for exports and views of one sample as generated)."""
    if not isinstance(sim, SimConfig):
        raise ValueError(f"sim: expected a SimConfig, got {type(sim).__name__}")
    sim = copy.deepcopy(sim)
    sim.data.augment = False
    sim.data.randomize.enabled = False
    sim.validate()
    return sim


def terrain_size(sim: SimConfig) -> int:
    extent = sim.data.map_size * sim.data.map_cell + 2 * sim.terrain.margin
    return grid_size(extent, sim.terrain.cell)


def make_terrains(batch: int, sim: SimConfig, seed, device: str, amplitude=None, feature_size=None) -> wp.array:
    """Stage 1: ``(batch, H, W)`` terrains covering the map plus its margin (fBm, or windows of
    the DEMs with ``terrain.source=dem``), obstacles placed within the map (or
    ``terrain.obstacle_region``); per-sample ``amplitude``/``feature_size`` override the
    config's (fBm only)."""
    data, terrain = sim.data, sim.terrain
    region = terrain.obstacle_region or 0.5 * data.map_size * data.map_cell
    return make_heightfields(
        batch, terrain_size(sim), terrain, seed, device, feature_size=feature_size, amplitude=amplitude, obstacle_region=region
    )


def make_clutter(heights: wp.array, sim: SimConfig, seed, device: str) -> CanopyLayer | None:
    """Stage 1b: the clutter layer over the terrains (``terrain.clutter``), placed like the
    obstacles; None when clutter is off (or none of it can be seen)."""
    data, terrain = sim.data, sim.terrain
    if not terrain.clutter.active:
        return None
    region = terrain.obstacle_region or 0.5 * data.map_size * data.map_cell
    return make_canopy(heights, terrain.clutter, terrain.cell, region, terrain.keep_out, seed, device)


def scan_terrains(heights: wp.array, sim: SimConfig, seed, device: str, canopy: CanopyLayer | None = None) -> tuple[wp.array, wp.array]:
    """Stage 2: the LIDAR scans ``(points, sensor_z)``, against the clutter ``canopy`` too if
    given; rays stop at the map's edge if ``clip_rays``."""
    data = sim.data
    reach = 0.5 * data.map_size * data.map_cell + sim.terrain.cell if data.clip_rays else 0.0
    return trace(heights, sim.terrain.cell, sim.lidar, seed, device, augment=data.augment, reach=reach, canopy=canopy)


def make_maps(
    heights: wp.array, points: wp.array, sensor_z: wp.array, sim: SimConfig, seed, device: str, canopy: CanopyLayer | None = None
) -> dict[str, wp.array]:
    """Stage 3: scan image, mask and max per cell from the points; the ground-truth map from the
    terrain (and, with a clutter ``canopy``, ``target_visible``: ground or canopy top, whichever
    is higher); image noise on observed cells if configured."""
    data, terrain = sim.data, sim.terrain
    batch = heights.shape[0]
    seed = as_seed(seed, device)
    grid = (batch, data.map_size, data.map_size)
    scan, scan_max, mask = bin_into_maps(points, data.map_size, data.map_cell, device, fill=data.fill)
    target = arena.empty(scan.shape, float, device)
    wp.launch(
        truth_kernels.cell_mean_heights,
        dim=grid,
        inputs=[heights, float(terrain.cell), sensor_z, float(data.map_cell), int(data.truth_samples), seed.array, int(bool(data.augment))],
        outputs=[target],
        device=device,
    )
    maps = dict(scan=scan, mask=mask, target=target, scan_max=scan_max)
    if canopy is not None:
        maps["target_visible"] = arena.empty(scan.shape, float, device)
        wp.launch(
            clutter_kernels.cell_mean_visible,
            dim=grid,
            inputs=[heights, canopy.top, canopy.density, float(terrain.cell), sensor_z, float(data.map_cell), int(data.truth_samples), seed.array, int(bool(data.augment))],
            outputs=[maps["target_visible"]],
            device=device,
        )
    if data.noise > 0:
        # the sample's height range, reduced per row then per sample (no contended atomics)
        row_lo, row_hi = (arena.empty((batch, data.map_size), float, device) for _ in range(2))
        wp.launch(projection_kernels.row_extremes, dim=(batch, data.map_size), inputs=[target], outputs=[row_lo, row_hi], device=device)
        height_range = arena.empty(batch, float, device)
        wp.launch(projection_kernels.height_range, dim=batch, inputs=[row_lo, row_hi], outputs=[height_range], device=device)
        wp.launch(projection_kernels.add_image_noise, dim=grid, inputs=[seed.array, float(data.noise), height_range, mask], outputs=[scan], device=device)
    return maps


def generate_batch(batch: int, cfg=None, seed: int = 0, device=None, heights=None) -> Batch:
    """Generate ``batch`` training pairs on ``device`` from ``seed``.

    Terrain -> LIDAR scan -> projected scan image and mask, and the ground-truth map, all in
    Warp launches over the whole batch (``make_terrains``, ``scan_terrains``, ``make_maps``).
    Sample ``b`` depends only on ``(cfg, seed, b)``.
    ``heights`` (optional, ``(batch, H, W)`` metres at ``cfg.terrain.cell`` spacing; Warp array,
    tensor or numpy) replaces the generated terrains; it must cover the map. With
    ``data.randomize.enabled`` the sensor, terrain and obstacles are drawn per batch from ``seed``
    (see ``sim/randomize.py``).
    """
    require(isinstance(batch, int) and not isinstance(batch, bool) and batch >= 1, "batch", batch, "must be an integer >= 1")
    require(isinstance(seed, int) and not isinstance(seed, bool), "seed", seed, "must be an integer")
    sim = as_sim_config(cfg)
    device = resolve_device(device)
    seed = int(seed) & 0x7FFFFFFF
    amplitude = feature_size = None
    if sim.data.randomize.enabled:
        sim, amplitude, feature_size = randomize(sim, batch, seed)
    if heights is not None:
        heights, shape = as_heightfields(heights)
    check_batch_fits(batch, terrain_size(sim) if heights is None else max(shape[1:]), sim.lidar.num_rays, sim.data.map_size, device,
                     scratch_bytes(sim.terrain))
    if heights is not None:
        require(shape[0] == batch, "heights", f"shape {shape}", f"needs batch={batch} terrains")
        reach = 0.5 * (min(shape[1], shape[2]) - 1) * sim.terrain.cell
        need = 0.5 * sim.data.map_size * sim.data.map_cell
        require(reach >= need, "heights", f"shape {shape}", f"covers +-{reach:g} m but the map needs +-{need:g} m")
    with torch_stream(device):  # on CUDA every launch below runs on torch's current stream
        if heights is not None and not isinstance(heights, wp.array):
            heights = to_warp(heights, wp.float32, device)
        return as_batch(run_stages(batch, sim, as_seed(seed, device), device, heights, amplitude, feature_size))


def run_stages(batch: int, sim: SimConfig, seed: Seed, device: str, heights: wp.array | None = None, amplitude=None,
               feature_size=None) -> dict[str, wp.array]:
    """The launches of one batch (terrains unless ``heights`` are given, clutter, scans, maps),
    every kernel reading ``seed.array``: the Warp arrays of a ``Batch``. The caller checks the
    arguments and picks the stream (``generate_batch``, ``sim/graph.py``)."""
    if heights is None:
        heights = make_terrains(batch, sim, seed, device, amplitude=amplitude, feature_size=feature_size)
    canopy = make_clutter(heights, sim, seed, device)
    points, sensor_z = scan_terrains(heights, sim, seed, device, canopy)
    arrays = make_maps(heights, points, sensor_z, sim, seed, device, canopy)
    arrays.update(points=points, heights=heights, sensor_z=sensor_z)
    return arrays


def as_batch(arrays: dict[str, wp.array]) -> Batch:
    """A ``Batch`` of torch tensors sharing memory with ``arrays`` (``run_stages``' output)."""
    tensors = {k: wp.to_torch(v) for k, v in arrays.items()}
    tensors["points"] = tensors["points"].view(arrays["points"].shape[0], -1, 3)
    return Batch(**tensors, warp_arrays=arrays)
