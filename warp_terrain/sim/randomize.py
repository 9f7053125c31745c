"""Domain randomisation: each batch a different world, so a model meets no single default.

Users' terrain and sensors differ from any training default. With ``data.randomize.enabled``,
every batch draws its own sensor (any preset), mount height, range noise, image noise (up to
``noise_max``), octave count and obstacle mix, and every sample its own relief amplitude and feature size (log-uniform, from
centimetres to metres and from a few metres to tens of metres). The draws come from the batch
seed, so a randomised stream is as reproducible as a fixed one. With ``terrain.source=dem`` the
relief is real ground: the amplitude, feature-size and octave draws do not apply to it; the
sensor, obstacles and noise are drawn as on fBm terrain. With ``dem_probability`` > 0 an fBm
world mixes in real ground: that share of batches cut their relief from ``terrain.dem``'s files.
With ``plain_probability`` > 0 a world with landforms (``terrain=wide``: tilt, low-frequency
relief, depressions, gullies, terraces) mixes in plain fBm: that share of batches has them off,
so one stream holds the paper's gently rolling ground as well as steep real-looking windows.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

import numpy as np

from ..core.checks import check_finite, require
from .landforms import LandformConfig
from .lidar import LIDAR_PRESETS, lidar_preset
from .terrain import OBSTACLE_KINDS, ObstacleConfig


@dataclass
class RandomizeConfig:
    """Ranges of the per-batch and per-sample draws (metres, degrees)."""

    enabled: bool = False
    amplitude_min: float = 0.05
    amplitude_max: float = 4.0
    feature_size_min: float = 3.0
    feature_size_max: float = 40.0
    octaves_min: int = 2
    octaves_max: int = 6
    lidars: list[str] = field(default_factory=lambda: list(LIDAR_PRESETS))
    mount_height_min: float = 1.2
    mount_height_max: float = 2.5
    range_noise_max: float = 0.03
    obstacle_probability: float = 0.4
    # per obstacle kind, the probability that a batch gets that kind, in place of
    # ``obstacle_probability`` (e.g. ``{pits: 0.8, ditches: 0.8}`` for a world richer in negative
    # obstacles); kinds not named keep ``obstacle_probability``. Each kind's draw is taken from the
    # batch's stream whatever its probability, so changing one moves no other draw.
    obstacle_probabilities: dict[str, float] = field(default_factory=dict)
    azimuth_step_min_deg: float = 0.4
    noise_max: float = 0.0
    # probability that a batch's relief is real ground: windows of ``terrain.dem`` (its files,
    # scale and window draws) instead of the fBm world, obstacles and sensor drawn as for fBm
    dem_probability: float = 0.0
    # probability that a batch is plain fBm: the terrain's tilt, relief and landforms off for it
    # (no effect on a terrain without them)
    plain_probability: float = 0.0

    def validate(self) -> None:
        for key in ("amplitude", "feature_size", "mount_height"):
            lo, hi = getattr(self, f"{key}_min"), getattr(self, f"{key}_max")
            check_finite(f"randomize.{key}_min", lo)
            check_finite(f"randomize.{key}_max", hi)
            require(lo > 0, f"randomize.{key}_min", lo, "must be > 0")
            require(hi >= lo, f"randomize.{key}_max", hi, f"must be >= {key}_min")
        require(1 <= self.octaves_min <= 16, "randomize.octaves_min", self.octaves_min, "must be in [1, 16]")
        require(self.octaves_min <= self.octaves_max <= 16, "randomize.octaves_max", self.octaves_max, "must be in [octaves_min, 16]")
        require(len(self.lidars) > 0, "randomize.lidars", self.lidars, "must name at least one preset")
        unknown = [name for name in self.lidars if name not in LIDAR_PRESETS]
        require(not unknown, "randomize.lidars", list(self.lidars), f"unknown preset(s) {', '.join(map(str, unknown))}; choose from {', '.join(LIDAR_PRESETS)}")
        require(0.0 <= self.range_noise_max < 1.0, "randomize.range_noise_max", self.range_noise_max, "must be in [0, 1)")
        require(0.0 <= self.obstacle_probability <= 1.0, "randomize.obstacle_probability", self.obstacle_probability, "must be in [0, 1]")
        require(0.0 <= self.noise_max <= 1.0, "randomize.noise_max", self.noise_max, "must be in [0, 1]")
        require(0.0 <= self.dem_probability <= 1.0, "randomize.dem_probability", self.dem_probability, "must be in [0, 1]")
        require(0.0 <= self.plain_probability <= 1.0, "randomize.plain_probability", self.plain_probability, "must be in [0, 1]")
        for kind, p in self.obstacle_probabilities.items():
            require(kind in OBSTACLE_KINDS, f"randomize.obstacle_probabilities.{kind}", p, f"unknown obstacle kind; choose from {', '.join(OBSTACLE_KINDS)}")
            check_finite(f"randomize.obstacle_probabilities.{kind}", p)
            require(0.0 <= p <= 1.0, f"randomize.obstacle_probabilities.{kind}", p, "must be in [0, 1]")
        require(self.azimuth_step_min_deg >= 0.0, "randomize.azimuth_step_min_deg", self.azimuth_step_min_deg, "must be >= 0")


# sizes of the obstacles a randomised batch may get, per kind (full widths / lengths / heights, m)
OBSTACLE_RANGES = {
    "cylinders": ObstacleConfig(count_min=1, count_max=8, width_min=0.3, width_max=2.5, height_min=0.3, height_max=3.0),
    "boxes": ObstacleConfig(count_min=1, count_max=5, width_min=0.5, width_max=3.0, length_min=1.0, length_max=5.0, height_min=0.3, height_max=2.5),
    "rocks": ObstacleConfig(count_min=1, count_max=8, width_min=0.4, width_max=3.0, height_min=0.2, height_max=1.5),
    "pits": ObstacleConfig(count_min=1, count_max=5, width_min=0.6, width_max=3.0, height_min=0.3, height_max=2.0),
    "ditches": ObstacleConfig(count_min=1, count_max=3, width_min=0.5, width_max=2.5, length_min=3.0, length_max=12.0, height_min=0.3, height_max=1.5),
}


def log_uniform(rng: np.random.Generator, lo: float, hi: float, size: int) -> np.ndarray:
    return np.exp(rng.uniform(math.log(lo), math.log(hi), size)).astype(np.float32)


def randomize(sim, batch: int, seed: int):
    """``(sim_for_this_batch, amplitudes, feature_sizes)`` drawn from ``seed``."""
    r: RandomizeConfig = sim.data.randomize
    rng = np.random.default_rng([seed, 0x5EED])
    out = copy.deepcopy(sim)
    name = r.lidars[int(rng.integers(len(r.lidars)))]
    lidar = lidar_preset(name)
    lidar.mount_height = float(rng.uniform(r.mount_height_min, r.mount_height_max))
    lidar.range_noise_std = float(rng.uniform(0.0, r.range_noise_max))
    if r.azimuth_step_min_deg > lidar.azimuth_step_deg:
        lidar.azimuth_step_deg = r.azimuth_step_min_deg
    out.lidar = lidar
    out.terrain.octaves = int(rng.integers(r.octaves_min, r.octaves_max + 1))
    for kind in OBSTACLE_KINDS:
        chosen = rng.uniform() < r.obstacle_probabilities.get(kind, r.obstacle_probability)
        setattr(out.terrain, kind, copy.deepcopy(OBSTACLE_RANGES[kind]) if chosen else ObstacleConfig())
    if r.noise_max > 0:
        out.data.noise = float(rng.uniform(0.0, r.noise_max))
    amplitudes = log_uniform(rng, r.amplitude_min, r.amplitude_max, batch)
    feature_sizes = log_uniform(rng, r.feature_size_min, r.feature_size_max, batch)
    if r.dem_probability > 0 and rng.uniform() < r.dem_probability:  # drawn last: other streams unchanged
        out.terrain.source = "dem"
    if r.plain_probability > 0 and rng.uniform() < r.plain_probability:  # after the DEM draw: its stream unchanged
        out.terrain.tilt.enabled = False
        out.terrain.relief.enabled = False
        out.terrain.landforms = LandformConfig()
    return out, amplitudes, feature_sizes
