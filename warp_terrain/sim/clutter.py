"""Clutter above the ground (bushes, grass, tree crowns): its config and the canopy layer the
rays are cast against (``kernels/clutter.py``, ``kernels/raycast.py``)."""

from __future__ import annotations

from dataclasses import dataclass, fields

import warp as wp

from ..core.checks import check_finite, require
from ..kernels import clutter as clutter_kernels
from ..kernels import raycast as raycast_kernels
from . import arena
from .arena import as_seed

COUNTS = ("bushes", "trees")
RANGES = ("bush_radius", "bush_height", "crown_radius", "crown_lift", "crown_depth", "grass_height")
DENSITIES = ("bush_density", "crown_density", "grass_density")


@dataclass
class ClutterConfig:
    """Vegetation and overhangs above the ground, off by default (``enabled=false``: every scan,
    map and target is exactly what it is without this section).

    Each sample draws its own clutter from its seed (sample ``b`` depends only on
    ``(seed, b)``), placed like obstacles in the square ``+-terrain.obstacle_region`` m around
    the sensor (0: the map's half extent), ``terrain.keep_out`` m clear of it:

    - ``bushes_min``..``bushes_max`` bushes (count per sample): porous half-ellipsoids standing
      on the ground, radius ``bush_radius_min``..``bush_radius_max`` m, height
      ``bush_height_min``..``bush_height_max`` m above the ground at their centre
    - ``trees_min``..``trees_max`` tree crowns (count per sample): ellipsoids of radius
      ``crown_radius_min``..``crown_radius_max`` m whose bottom floats
      ``crown_lift_min``..``crown_lift_max`` m above the ground at the tree's foot and that are
      ``crown_depth_min``..``crown_depth_max`` m deep: rays can pass under a crown and hit the
      ground, or hit the crown (no trunks)
    - grass: square patches of ``grass_patch`` m, each covered with probability ``grass_cover``
      (the share of the ground under grass, in [0, 1]) by a layer
      ``grass_height_min``..``grass_height_max`` m tall

    ``*_density`` (per metre, in [0, 1]) is the probability that a ray returns per metre it
    travels inside that kind of clutter (1: solid, 0: invisible): a ray crossing ``L`` m of it
    returns with probability ``1 - (1 - density)^L``, at the point where it entered. Where kinds
    overlap, the higher kind wins (crown over bush over grass).

    Ground truth under clutter: ``Batch.target`` stays the bare ground surface averaged over
    each map cell (what the model must reconstruct for driving); with clutter on the batch also
    carries ``Batch.target_visible``, the highest surface the LIDAR could see from above (the
    higher of the ground and the canopy top at each of the ground truth's sub-cell points,
    averaged the same way), so ``target_visible >= target``. Scans with clutter walk every ray
    on its own (``cast_rays``), not by azimuth column.
    """

    enabled: bool = False
    bushes_min: int = 0
    bushes_max: int = 8
    bush_radius_min: float = 0.3
    bush_radius_max: float = 1.2
    bush_height_min: float = 0.3
    bush_height_max: float = 1.5
    bush_density: float = 0.6
    trees_min: int = 0
    trees_max: int = 3
    crown_radius_min: float = 1.5
    crown_radius_max: float = 4.0
    crown_lift_min: float = 2.0
    crown_lift_max: float = 6.0
    crown_depth_min: float = 1.5
    crown_depth_max: float = 4.0
    crown_density: float = 0.7
    grass_cover: float = 0.3
    grass_patch: float = 2.0
    grass_height_min: float = 0.1
    grass_height_max: float = 0.5
    grass_density: float = 0.5

    def validate(self, name: str = "clutter") -> None:
        require(isinstance(self.enabled, bool), f"{name}.enabled", self.enabled, "must be true or false")
        for key in COUNTS:
            lo, hi = getattr(self, f"{key}_min"), getattr(self, f"{key}_max")
            require(isinstance(lo, int) and lo >= 0, f"{name}.{key}_min", lo, "must be an integer >= 0")
            require(isinstance(hi, int) and hi >= lo, f"{name}.{key}_max", hi, f"must be an integer >= {key}_min")
        for key in RANGES:
            lo, hi = getattr(self, f"{key}_min"), getattr(self, f"{key}_max")
            check_finite(f"{name}.{key}_min", lo)
            check_finite(f"{name}.{key}_max", hi)
            require(lo >= 0 if key == "crown_lift" else lo > 0, f"{name}.{key}_min", lo, "must be >= 0" if key == "crown_lift" else "must be > 0")
            require(hi >= lo, f"{name}.{key}_max", hi, f"must be >= {key}_min")
        for key in (*DENSITIES, "grass_cover"):
            check_finite(f"{name}.{key}", getattr(self, key))
            require(0.0 <= getattr(self, key) <= 1.0, f"{name}.{key}", getattr(self, key), "must be in [0, 1]")
        check_finite(f"{name}.grass_patch", self.grass_patch)
        require(self.grass_patch > 0, f"{name}.grass_patch", self.grass_patch, "must be > 0")

    @property
    def active(self) -> bool:
        """Whether any clutter can be seen: enabled, with some kind present at a density > 0.
        An inactive config leaves the scan exactly as without clutter (column walk included)."""
        return self.enabled and (
            (self.bushes_max > 0 and self.bush_density > 0)
            or (self.trees_max > 0 and self.crown_density > 0)
            or (self.grass_cover > 0 and self.grass_density > 0)
        )


@dataclass
class CanopyLayer:
    """A batch's canopy: ``(batch, H-1, W-1)`` Warp arrays ``bottom``, ``top`` (world metres,
    NaN where empty) and ``density`` (per metre), one value per terrain cell."""

    bottom: wp.array
    top: wp.array
    density: wp.array

    def struct(self) -> raycast_kernels.Canopy:
        """The layer as the ray caster takes it (``on``)."""
        canopy = raycast_kernels.Canopy()
        canopy.bottom, canopy.top, canopy.density = self.bottom, self.top, self.density
        canopy.on = 1
        canopy.key = 0
        canopy.metres = 1.0
        return canopy


def no_canopy(device: str) -> raycast_kernels.Canopy:
    """The ray caster's canopy when there is no clutter (``on = 0``, empty arrays)."""
    empty = arena.zeros((1, 1, 1), float, device)
    canopy = raycast_kernels.Canopy()
    canopy.bottom = canopy.top = canopy.density = empty
    canopy.on = 0
    canopy.key = 0
    canopy.metres = 1.0
    return canopy


def _spec(cfg: ClutterConfig, region: float, keep_out: float) -> clutter_kernels.ClutterSpec:
    spec = clutter_kernels.ClutterSpec()
    for f in fields(cfg):
        if f.name != "enabled":
            setattr(spec, f.name, getattr(cfg, f.name))
    # a kind that cannot be seen is not drawn
    if cfg.bush_density <= 0:
        spec.bushes_min = spec.bushes_max = 0
    if cfg.crown_density <= 0:
        spec.trees_min = spec.trees_max = 0
    if cfg.grass_density <= 0:
        spec.grass_cover = 0.0
    spec.region = float(region)
    spec.keep_out = float(keep_out)
    return spec


def make_canopy(heights: wp.array, cfg: ClutterConfig, cell: float, region: float, keep_out: float, seed, device: str, first: int = 0) -> CanopyLayer:
    """The canopy layer over ``heights`` (``(batch, H, W)`` world metres at ``cell`` spacing):
    items drawn per sample (numbered from ``first``) within ``+-region`` m, ``keep_out`` m
    clear of the sensor, then stamped per cell (``kernels/clutter.py``)."""
    batch, H, W = heights.shape
    seed = as_seed(seed, device)
    spec = _spec(cfg, region, keep_out)
    slots = max(spec.bushes_max + spec.trees_max, 1)
    items = arena.empty((batch, slots), clutter_kernels.ClutterItem, device)
    wp.launch(clutter_kernels.sample_items, dim=items.shape, inputs=[seed.array, int(first), spec, heights, float(cell)], outputs=[items], device=device)
    layer = CanopyLayer(*(arena.empty((batch, H - 1, W - 1), float, device) for _ in range(3)))
    wp.launch(
        clutter_kernels.stamp_canopy,
        dim=layer.top.shape,
        inputs=[seed.array, int(first), spec, items, heights, float(cell)],
        outputs=[layer.bottom, layer.top, layer.density],
        device=device,
    )
    return layer
