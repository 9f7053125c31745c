"""The run configuration: one structured config per module, composed by Hydra.

``RunConfig`` is the schema of ``conf/config.yaml``; each group in ``conf/`` fills one of its
fields (``terrain/``, ``lidar/``, ``model/``, ``train/``) and ``experiment/`` files override
several at once. Because the schema is typed, a wrong type or an unknown key fails at start-up
with Hydra's own message; ``validate_run`` then checks ranges and consistency and names the
offending key (``terrain.octaves=-1: must be an integer >= 1``).

LIDAR presets are data with sources (``sim/lidar.py``); they are registered here as the
``lidar`` group, so ``lidar=vlp16`` selects one and ``lidar.dropout=0.1`` edits it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from .models.config import ModelConfig
from .sim.batch import DataConfig, SimConfig
from .sim.lidar import LIDAR_PRESETS, LidarConfig, lidar_preset
from .sim.terrain import TerrainConfig
from .training.config import TrainConfig


@dataclass
class RunConfig:
    terrain: TerrainConfig = field(default_factory=TerrainConfig)
    lidar: LidarConfig = field(default_factory=lambda: lidar_preset("hdl32e"))
    data: DataConfig = field(default_factory=DataConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    train: TrainConfig = field(default_factory=TrainConfig)

    def sim(self) -> SimConfig:
        return SimConfig(terrain=self.terrain, lidar=self.lidar, data=self.data)


def register_configs() -> None:
    """Put the schema and the LIDAR presets into Hydra's ConfigStore (idempotent)."""
    cs = ConfigStore.instance()
    cs.store(name="run_schema", node=RunConfig)
    for name in LIDAR_PRESETS:
        cs.store(group="lidar", name=name, node=lidar_preset(name))


def validate_run(cfg: RunConfig) -> RunConfig:
    """Check every section and their consistency; the error names the full key."""
    for section in ("terrain", "lidar", "data", "model", "train"):
        try:
            getattr(cfg, section).validate()
        except ValueError as err:
            raise ValueError(f"{section}.{err}") from None
    if cfg.model.name == "paper" and cfg.data.map_size != 121:
        raise ValueError(f"data.map_size={cfg.data.map_size}: model=paper is Table 2's net for 121x121 maps; use model=unet for other sizes")
    if cfg.model.in_channels not in (1, 2):
        raise ValueError(f"model.in_channels={cfg.model.in_channels}: inputs are the scan (1) or the scan and its mask (2)")
    if cfg.model.out_channels != 1:
        raise ValueError(f"model.out_channels={cfg.model.out_channels}: the generator predicts one height map (1)")
    _check_obstacle_room(cfg)
    return cfg


def _check_obstacle_room(cfg: RunConfig) -> None:
    """Obstacles need somewhere to stand: ``keep_out`` must leave part of their region free."""
    terrain = cfg.terrain
    if not terrain.has_obstacles():
        return
    region = terrain.obstacle_region or 0.5 * cfg.data.map_size * cfg.data.map_cell
    if terrain.keep_out >= region:
        raise ValueError(
            f"terrain.keep_out={terrain.keep_out}: leaves no room for obstacles in the +-{region:g} m "
            "region around the sensor (lower keep_out or raise terrain.obstacle_region)"
        )


def to_run_config(cfg) -> RunConfig:
    """A validated ``RunConfig`` from a Hydra ``DictConfig`` (or a ``RunConfig``)."""
    if isinstance(cfg, RunConfig):
        return validate_run(cfg)
    if not isinstance(cfg, DictConfig):
        cfg = OmegaConf.create(cfg)
    try:
        merged = OmegaConf.merge(OmegaConf.structured(RunConfig), cfg)
    except OmegaConfBaseException as err:  # wrong type or unknown key: one line naming it
        raise ValueError(f"{err.full_key}: {str(err.msg).splitlines()[0]}") from None
    return validate_run(OmegaConf.to_object(merged))
