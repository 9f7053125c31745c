"""The terrain presets: the paper's four data settings, as data.

Each preset is a :class:`~warp_terrain.sim.terrain.TerrainConfig`; the Hydra group ``terrain``
is registered from this table (``terrain=octave3``), every command finds them by name from any
folder, and ``TerrainConfig()`` is ``octave5``. Sources: the paper (Sutavani et al.), Sec. 3:
Perlin terrain of "octaves" 3 and 5; flat ground with cylindrical obstacles; slight terrain with
negative obstacles (holes and ditches) the LIDAR cannot see into. Sizes are ours (the paper
gives none): relief of +-2 m over 20 m features at true scale on a 30 m map, obstacles of
vehicle-relevant size. ``dem`` takes real ground from elevation rasters the user names
(``terrain=dem terrain.dem.files=[a.tif]``, ``sim/dem.py``); it needs those files, so it is not
one of the settings ``terrain_preset_names`` (and ``all``) run as they are. ``wide`` is a wider
synthetic world covering what real 30 m windows of ground do (tilts of 0-35 degrees, relief of
up to ~15 m across the map, depressions, gullies and terraces now and then, up to 40 obstacles
of a kind); it is not one of the paper's settings, so ``all`` leaves it out too.
"""

from __future__ import annotations

import copy

from .batch import DataConfig, SimConfig
from .clutter import ClutterConfig
from .dem import DemConfig
from .landforms import LandformConfig, ReliefConfig, TiltConfig
from .terrain import ObstacleConfig, TerrainConfig

TERRAIN_PRESETS: dict[str, TerrainConfig] = {
    # smooth rolling fBm Perlin terrain
    "octave3": TerrainConfig(name="octave3", octaves=3),
    # the same relief with two finer octaves of detail (the default)
    "octave5": TerrainConfig(name="octave5", octaves=5),
    # flat ground with vertical cylinders
    "flat_cylinders": TerrainConfig(
        name="flat_cylinders", octaves=1, amplitude=0.0,
        cylinders=ObstacleConfig(count_min=4, count_max=10, width_min=0.5, width_max=2.5, height_min=0.5, height_max=2.5),
    ),
    # slight terrain with pits and ditches the LIDAR cannot see into
    "negative_obstacles": TerrainConfig(
        name="negative_obstacles", octaves=4, feature_size=12.0, amplitude=0.3,
        pits=ObstacleConfig(count_min=2, count_max=5, width_min=1.0, width_max=3.0, height_min=0.5, height_max=1.5),
        ditches=ObstacleConfig(count_min=1, count_max=3, width_min=0.8, width_max=2.0, length_min=4.0, length_max=12.0,
                               height_min=0.5, height_max=1.5),
    ),
    # a wider world: tilt, low-frequency relief, landforms, up to 90 obstacles of every kind, clutter
    "wide": TerrainConfig(
        name="wide", octaves=5, feature_size=20.0, amplitude=1.0,
        tilt=TiltConfig(enabled=True, slope_min_deg=0.0, slope_max_deg=35.0),
        relief=ReliefConfig(enabled=True, octaves=2, wavelength_min=60.0, wavelength_max=400.0, amplitude_min=0.0, amplitude_max=7.0),
        landforms=LandformConfig(
            depressions_min=0, depressions_max=2, depression_radius_min=4.0, depression_radius_max=15.0,
            depression_depth_min=0.3, depression_depth_max=2.0,
            gullies_min=0, gullies_max=1, gully_width_min=4.0, gully_width_max=12.0, gully_depth_min=0.5, gully_depth_max=2.0,
            gully_meander_max=3.0, gully_wavelength_min=15.0, gully_wavelength_max=50.0,
            terrace_probability=0.25, terrace_rise_min=0.5, terrace_rise_max=2.0, terrace_tread_min=0.2, terrace_tread_max=0.5,
        ),
        cylinders=ObstacleConfig(count_min=0, count_max=30, width_min=0.2, width_max=1.5, height_min=0.5, height_max=3.0),
        boxes=ObstacleConfig(count_min=0, count_max=12, width_min=0.5, width_max=3.0, length_min=1.0, length_max=6.0,
                             height_min=0.3, height_max=2.5),
        rocks=ObstacleConfig(count_min=0, count_max=30, width_min=0.3, width_max=2.5, height_min=0.2, height_max=1.5),
        pits=ObstacleConfig(count_min=0, count_max=12, width_min=0.5, width_max=3.0, height_min=0.3, height_max=1.5),
        ditches=ObstacleConfig(count_min=0, count_max=6, width_min=0.5, width_max=2.0, length_min=3.0, length_max=12.0,
                               height_min=0.3, height_max=1.5),
        clutter=ClutterConfig(enabled=True),  # bushes, a few tree crowns, grass: returns from above the ground
    ),
    # real ground: true-scale windows of elevation rasters, random heading and mirror (give the files)
    "dem": TerrainConfig(name="dem", source="dem", dem=DemConfig()),
}


BEYOND_THE_PAPER = ("wide",)  # presets ``all`` leaves out


def terrain_preset_names() -> list[str]:
    """The names of the presets that run as they are (what ``all`` means), sorted: the paper's
    settings, i.e. every preset but those that need the user's files (``dem``) and ``wide``."""
    return sorted(name for name, terrain in TERRAIN_PRESETS.items() if terrain.source == "fbm" and name not in BEYOND_THE_PAPER)


def terrain_preset(name: str) -> TerrainConfig:
    """A fresh copy of the terrain preset ``name``."""
    if name not in TERRAIN_PRESETS:
        raise ValueError(f"terrain={name!r}: unknown terrain setting; choose from {', '.join(sorted(TERRAIN_PRESETS))}")
    return copy.deepcopy(TERRAIN_PRESETS[name])


def preset_sim(name: str, augment: bool = False) -> SimConfig:
    """A validated ``SimConfig``: the terrain preset ``name`` with the default sensor and maps,
    ``data.augment`` set to ``augment``."""
    sim = SimConfig(terrain=terrain_preset(name), data=DataConfig(augment=bool(augment)))
    sim.validate()
    return sim
