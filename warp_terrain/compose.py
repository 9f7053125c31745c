"""Hydra composition: the schema and presets registered, configs turned into ``RunConfig``.

``RunConfig`` (``training.config``) is the schema of ``conf/config.yaml``; each group in
``conf/`` fills one of its fields and ``experiment/`` files override several at once. The YAML
files ship inside the package as ``warp_terrain.conf`` (the repository's ``conf/`` folder), so
an installed wheel composes the same runs from any folder. Because the schema is typed, a wrong
type or an unknown key fails at start-up with one line naming the key; ``validate_run`` then
checks ranges and consistency (``terrain.octaves=-1: must be an integer >= 1``).

LIDAR presets (``sim/lidar.py``), terrain presets (``sim/presets.py``) and model presets
(``models/presets.py``) are data with sources; they are registered here as the ``lidar``,
``terrain`` and ``model`` groups, so ``lidar=vlp16`` selects
one and ``lidar.dropout=0.1`` edits it.
"""

from __future__ import annotations

from pathlib import Path

from hydra import compose, initialize_config_module
from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from .models.presets import MODEL_PRESETS
from .sim.batch import DataConfig, SimConfig
from .sim.lidar import LIDAR_PRESETS, lidar_preset
from .sim.presets import TERRAIN_PRESETS, preset_sim, terrain_preset_names
from .training.config import RunConfig, validate_run

#: Where the YAML configs live inside the package (Hydra's ``pkg://`` search path).
CONFIG_MODULE = "warp_terrain.conf"
CONFIG_PATH = f"pkg://{CONFIG_MODULE}"
CONFIG_NAME = "config"


def register_configs() -> None:
    """Put the schema and the LIDAR and terrain presets into Hydra's ConfigStore (idempotent)."""
    cs = ConfigStore.instance()
    cs.store(name="run_schema", node=RunConfig)
    for name in LIDAR_PRESETS:
        cs.store(group="lidar", name=name, node=lidar_preset(name))
    for name, terrain in TERRAIN_PRESETS.items():
        cs.store(group="terrain", name=name, node=terrain)
    for name, model in MODEL_PRESETS.items():
        cs.store(group="model", name=name, node=model)


def to_run_config(cfg, files: bool = True) -> RunConfig:
    """A validated ``RunConfig`` from a Hydra ``DictConfig`` (or a ``RunConfig``); ``files=False``
    leaves the DEM rasters it names unopened (``validate_run``)."""
    if isinstance(cfg, RunConfig):
        return validate_run(cfg, files)
    if not isinstance(cfg, DictConfig):
        cfg = OmegaConf.create(cfg)
    try:
        merged = OmegaConf.merge(OmegaConf.structured(RunConfig), cfg)
    except OmegaConfBaseException as err:  # wrong type or unknown key: one line naming it
        raise ValueError(f"{err.full_key}: {str(err.msg).splitlines()[0]}") from None
    return validate_run(OmegaConf.to_object(merged), files)


def compose_run(overrides: list[str] | tuple[str, ...] = (), files: bool = True) -> RunConfig:
    """The ``RunConfig`` that ``python train.py OVERRIDES`` runs (no run folder, no logging);
    ``files=False`` composes a recipe whose DEM rasters are not on this machine."""
    register_configs()
    with initialize_config_module(config_module=CONFIG_MODULE, version_base="1.3"):
        cfg = compose(config_name=CONFIG_NAME, overrides=list(overrides))
    cfg = OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"]) if "hydra" in cfg else cfg
    return to_run_config(cfg, files)


def terrain_setting_names() -> list[str]:
    """The terrain presets' names (``sim.presets``), sorted."""
    return terrain_preset_names()


def load_terrain_setting(name: str, augment: bool = False) -> SimConfig:
    """A validated ``SimConfig``: the terrain preset ``name``, or the terrain in a YAML file at
    the path ``name`` (fields of ``TerrainConfig``), with the default sensor and maps and
    ``data.augment`` set to ``augment``."""
    path = Path(name)
    if path.suffix not in (".yaml", ".yml"):
        if name not in TERRAIN_PRESETS:
            raise ValueError(f"terrain={name!r}: unknown terrain setting; choose from {', '.join(sorted(TERRAIN_PRESETS))} or a .yaml path")
        return preset_sim(name, augment)
    if not path.is_file():
        raise ValueError(f"terrain={name!r}: no such file")
    try:
        merged = OmegaConf.merge(
            OmegaConf.structured(SimConfig),
            {"terrain": OmegaConf.load(path), "data": OmegaConf.structured(DataConfig(augment=bool(augment)))},
        )
        sim = OmegaConf.to_object(merged)
    except (OmegaConfBaseException, OSError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ValueError(f"terrain={name!r}: cannot load {path}: {first}") from None
    except Exception as e:  # YAML syntax errors and the like
        raise ValueError(f"terrain={name!r}: cannot read {path}: {type(e).__name__}") from None
    sim.validate()
    return sim
