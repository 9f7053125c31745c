"""Landforms on fBm terrain (``kernels/landforms.py``): a planar tilt, low-frequency relief,
closed depressions, gullies and terraces, each behind a ``TerrainConfig`` group that is off by
default (``terrain.tilt``, ``terrain.relief``, ``terrain.landforms``).

Real 30 m windows of ground carry tilts of 10-30 degrees, relief of metres across the map,
closed depressions, gullies and terraces; plain fBm has none of these. Every draw is made on
the device from the sample's terrain stream, so sample ``b`` depends only on ``(seed, b)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import warp as wp

from ..core.checks import check_finite, require
from ..kernels import landforms as landform_kernels
from . import arena
from .arena import as_seed

MAX_SLOPE_DEG = 60.0
MAX_RELIEF_OCTAVES = 4
MAX_TREAD = 0.9  # a tread of the whole step would leave a vertical riser


def _check_range(name: str, key: str, lo, hi, low: float, strict: bool) -> None:
    """``{key}_min`` finite and > ``low`` (>= if not ``strict``), ``{key}_max`` finite and >= it."""
    check_finite(f"{name}.{key}_min", lo)
    check_finite(f"{name}.{key}_max", hi)
    require(lo > low if strict else lo >= low, f"{name}.{key}_min", lo, f"must be {'>' if strict else '>='} {low:g}")
    require(hi >= lo, f"{name}.{key}_max", hi, f"must be >= {key}_min")


def _check_bool(name: str, value) -> None:
    require(isinstance(value, bool), name, value, "must be true or false")


def _check_count(name: str, key: str, lo, hi) -> None:
    require(isinstance(lo, int) and not isinstance(lo, bool) and lo >= 0, f"{name}.{key}_min", lo, "must be an integer >= 0")
    require(isinstance(hi, int) and not isinstance(hi, bool) and hi >= lo, f"{name}.{key}_max", hi, f"must be an integer >= {key}_min")


@dataclass
class TiltConfig:
    """A planar tilt per sample through the sensor: slope uniform in
    [``slope_min_deg``, ``slope_max_deg``] degrees, direction uniform in [0, 360)."""

    enabled: bool = False
    slope_min_deg: float = 0.0
    slope_max_deg: float = 30.0

    def validate(self, name: str = "tilt") -> None:
        _check_bool(f"{name}.enabled", self.enabled)
        check_finite(f"{name}.slope_min_deg", self.slope_min_deg)
        check_finite(f"{name}.slope_max_deg", self.slope_max_deg)
        require(self.slope_min_deg >= 0, f"{name}.slope_min_deg", self.slope_min_deg, "must be >= 0 (degrees)")
        require(self.slope_max_deg >= self.slope_min_deg, f"{name}.slope_max_deg", self.slope_max_deg, "must be >= slope_min_deg")
        require(self.slope_max_deg <= MAX_SLOPE_DEG, f"{name}.slope_max_deg", self.slope_max_deg, f"must be <= {MAX_SLOPE_DEG:g}")


@dataclass
class ReliefConfig:
    """Low-frequency relief added to the fBm: ``amplitude * fBm`` of ``octaves`` octaves (each
    twice finer and half as strong), the first of wavelength uniform in
    [``wavelength_min``, ``wavelength_max``] metres, amplitude uniform in
    [``amplitude_min``, ``amplitude_max``] metres (heights within +-amplitude)."""

    enabled: bool = False
    octaves: int = 2
    wavelength_min: float = 60.0
    wavelength_max: float = 400.0
    amplitude_min: float = 0.0
    amplitude_max: float = 7.0

    def validate(self, name: str = "relief") -> None:
        _check_bool(f"{name}.enabled", self.enabled)
        ok = isinstance(self.octaves, int) and not isinstance(self.octaves, bool) and 1 <= self.octaves <= MAX_RELIEF_OCTAVES
        require(ok, f"{name}.octaves", self.octaves, f"must be an integer in [1, {MAX_RELIEF_OCTAVES}]")
        _check_range(name, "wavelength", self.wavelength_min, self.wavelength_max, 0.0, strict=True)
        _check_range(name, "amplitude", self.amplitude_min, self.amplitude_max, 0.0, strict=False)


@dataclass
class LandformConfig:
    """Closed depressions, gullies and terraces (lengths in metres); all off by default.

    Depressions: ``depressions_min..max`` bowls per sample, radius and depth uniform in their
    ranges, centres anywhere on the terrain. Gullies: ``gullies_min..max`` channels crossing the
    terrain along a sine meander of amplitude uniform in [0, ``gully_meander_max``] and
    wavelength in [``gully_wavelength_min``, ``gully_wavelength_max``], full width and depth
    uniform in their ranges, a cross-section between V and U. Terraces: with probability
    ``terrace_probability`` a sample's heights are quantised into smooth steps of rise uniform in
    [``terrace_rise_min``, ``terrace_rise_max``], flat for a share of each step uniform in
    [``terrace_tread_min``, ``terrace_tread_max``].
    """

    depressions_min: int = 0
    depressions_max: int = 0
    depression_radius_min: float = 3.0
    depression_radius_max: float = 10.0
    depression_depth_min: float = 0.3
    depression_depth_max: float = 1.5
    gullies_min: int = 0
    gullies_max: int = 0
    gully_width_min: float = 2.0
    gully_width_max: float = 6.0
    gully_depth_min: float = 0.3
    gully_depth_max: float = 1.5
    gully_meander_max: float = 3.0
    gully_wavelength_min: float = 15.0
    gully_wavelength_max: float = 40.0
    terrace_probability: float = 0.0
    terrace_rise_min: float = 0.3
    terrace_rise_max: float = 1.5
    terrace_tread_min: float = 0.2
    terrace_tread_max: float = 0.6

    def validate(self, name: str = "landforms") -> None:
        _check_count(name, "depressions", self.depressions_min, self.depressions_max)
        _check_count(name, "gullies", self.gullies_min, self.gullies_max)
        for key in ("depression_radius", "depression_depth", "gully_width", "gully_depth", "gully_wavelength", "terrace_rise"):
            _check_range(name, key, getattr(self, f"{key}_min"), getattr(self, f"{key}_max"), 0.0, strict=True)
        check_finite(f"{name}.gully_meander_max", self.gully_meander_max)
        require(self.gully_meander_max >= 0, f"{name}.gully_meander_max", self.gully_meander_max, "must be >= 0")
        check_finite(f"{name}.terrace_probability", self.terrace_probability)
        require(0.0 <= self.terrace_probability <= 1.0, f"{name}.terrace_probability", self.terrace_probability, "must be in [0, 1]")
        _check_range(name, "terrace_tread", self.terrace_tread_min, self.terrace_tread_max, 0.0, strict=False)
        require(self.terrace_tread_max <= MAX_TREAD, f"{name}.terrace_tread_max", self.terrace_tread_max, f"must be <= {MAX_TREAD:g}")

    def enabled(self) -> bool:
        return self.depressions_max > 0 or self.gullies_max > 0 or self.terrace_probability > 0


class LandformDraws(NamedTuple):
    """Every sample's draws (``kernels/landforms.py`` structs), as ``draw_landforms`` leaves them."""

    params: wp.array  # (batch,) SampleLandforms
    fields: wp.array  # (batch, relief octaves) noise fields
    offsets: wp.array  # (batch, relief octaves) noise offsets
    depressions: wp.array  # (batch, max(depressions_max, 1)) Depression
    gullies: wp.array  # (batch, max(gullies_max, 1)) Gully


def landform_scratch_bytes(relief: ReliefConfig, forms: LandformConfig) -> int:
    """Bytes per sample ``draw_landforms`` allocates."""
    size = wp.types.type_size_in_bytes
    return (
        size(landform_kernels.SampleLandforms)
        + relief.octaves * (4 + 8)
        + max(forms.depressions_max, 1) * size(landform_kernels.Depression)
        + max(forms.gullies_max, 1) * size(landform_kernels.Gully)
    )


def landform_spec(tilt: TiltConfig, relief: ReliefConfig, forms: LandformConfig, extent: float) -> landform_kernels.LandformSpec:
    """The kernels' ``LandformSpec`` (angles in radians); centres within +-``extent`` metres."""
    spec = landform_kernels.LandformSpec()
    spec.slope_min = math.radians(tilt.slope_min_deg)
    spec.slope_max = math.radians(tilt.slope_max_deg)
    spec.relief_wavelength_min = relief.wavelength_min
    spec.relief_wavelength_max = relief.wavelength_max
    spec.relief_amplitude_min = relief.amplitude_min
    spec.relief_amplitude_max = relief.amplitude_max
    for key in ("terrace_probability", "terrace_rise_min", "terrace_rise_max", "terrace_tread_min", "terrace_tread_max",
                "depressions_min", "depressions_max", "depression_radius_min", "depression_radius_max",
                "depression_depth_min", "depression_depth_max", "gullies_min", "gullies_max", "gully_width_min",
                "gully_width_max", "gully_depth_min", "gully_depth_max", "gully_meander_max",
                "gully_wavelength_min", "gully_wavelength_max"):
        setattr(spec, key, getattr(forms, key))
    spec.extent = float(extent)
    return spec


def draw_landforms(batch: int, size: int, cell: float, tilt: TiltConfig, relief: ReliefConfig, forms: LandformConfig,
                   seed, device: str, first: int = 0) -> LandformDraws:
    """Draw samples ``first .. first + batch - 1``'s landforms on ``device`` (one launch)."""
    draws = LandformDraws(
        params=arena.empty(batch, landform_kernels.SampleLandforms, device),
        fields=arena.empty((batch, relief.octaves), wp.uint32, device),
        offsets=arena.empty((batch, relief.octaves), wp.vec2, device),
        depressions=arena.empty((batch, max(forms.depressions_max, 1)), landform_kernels.Depression, device),
        gullies=arena.empty((batch, max(forms.gullies_max, 1)), landform_kernels.Gully, device),
    )
    spec = landform_spec(tilt, relief, forms, 0.5 * (size - 1) * cell)
    wp.launch(landform_kernels.draw_landforms, dim=batch, inputs=[as_seed(seed, device).array, int(first), spec], outputs=list(draws), device=device)
    return draws


def add_landforms(heights: wp.array, cell: float, tilt: TiltConfig, relief: ReliefConfig, forms: LandformConfig,
                  seed, device: str, first: int = 0) -> None:
    """Lay the enabled landforms on ``heights`` in place: relief, tilt, terraces, then the cuts
    (depressions and gullies), one launch each; nothing when all are off."""
    if not (tilt.enabled or relief.enabled or forms.enabled()):
        return
    batch, size = heights.shape[0], heights.shape[1]
    draws = draw_landforms(batch, size, cell, tilt, relief, forms, seed, device, first)
    if relief.enabled:
        wp.launch(landform_kernels.add_relief, dim=heights.shape, inputs=[draws.fields, draws.offsets, draws.params, float(cell)],
                  outputs=[heights], device=device)
    if tilt.enabled:
        wp.launch(landform_kernels.add_tilt, dim=heights.shape, inputs=[draws.params, float(cell)], outputs=[heights], device=device)
    if forms.terrace_probability > 0:
        wp.launch(landform_kernels.add_terraces, dim=heights.shape, inputs=[draws.params], outputs=[heights], device=device)
    if forms.depressions_max > 0 or forms.gullies_max > 0:
        wp.launch(landform_kernels.carve, dim=heights.shape, inputs=[draws.depressions, draws.gullies, float(cell)],
                  outputs=[heights], device=device)
