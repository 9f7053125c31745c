"""The terrain presets: the paper's four data settings, as data.

Each preset is a :class:`~warp_terrain.sim.terrain.TerrainConfig`; the Hydra group ``terrain``
is registered from this table (``terrain=octave3``), every command finds them by name from any
folder, and ``TerrainConfig()`` is ``octave5``. Sources: the paper (Sutavani et al.), Sec. 3:
Perlin terrain of "octaves" 3 and 5; flat ground with cylindrical obstacles; slight terrain with
negative obstacles (holes and ditches) the LIDAR cannot see into. Sizes are ours (the paper
gives none): relief of +-2 m over 20 m features at true scale on a 30 m map, obstacles of
vehicle-relevant size. ``dem`` takes real ground from elevation rasters the user names
(``terrain=dem terrain.dem.files=[a.tif]``, ``sim/dem.py``); it needs those files, so it is not
one of the settings ``terrain_preset_names`` (and ``all``) run as they are.
"""

from __future__ import annotations

import copy

from .batch import DataConfig, SimConfig
from .dem import DemConfig
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
    # real ground: true-scale windows of elevation rasters, random heading and mirror (give the files)
    "dem": TerrainConfig(name="dem", source="dem", dem=DemConfig()),
}


def terrain_preset_names() -> list[str]:
    """The names of the presets that run as they are (what ``all`` means), sorted: every
    preset but those that need the user's files (``dem``)."""
    return sorted(name for name, terrain in TERRAIN_PRESETS.items() if terrain.source == "fbm")


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
