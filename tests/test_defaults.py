"""One source of defaults: the dataclasses are what ``python train.py`` runs, the presets are
single definitions, and the map's geometry is defined once."""

from __future__ import annotations

import dataclasses

import numpy as np
from conftest import run_config

import warp_terrain as wt
from warp_terrain.core.geometry import MAP_CELL, MAP_SIZE, MapGeometry
from warp_terrain.models import ModelConfig
from warp_terrain.models.presets import MODEL_PRESETS
from warp_terrain.sim import DataConfig, SimConfig, TerrainConfig
from warp_terrain.sim.presets import TERRAIN_PRESETS
from warp_terrain.training import RunConfig


def test_the_dataclass_defaults_are_what_train_py_composes():
    composed = run_config()
    assert composed == RunConfig()
    assert composed.sim() == SimConfig()


def test_presets_compose_to_their_tables():
    for name, terrain in TERRAIN_PRESETS.items():
        if terrain.source == "fbm":
            assert run_config(f"terrain={name}").terrain == terrain, name
    for name, model in MODEL_PRESETS.items():
        assert run_config(f"model={name}").model == model, name
    assert TerrainConfig() == TERRAIN_PRESETS["octave5"]
    assert MODEL_PRESETS["paper"] == ModelConfig()
    assert RunConfig().model == MODEL_PRESETS["fill_residual"]


def test_the_map_geometry_is_defined_once():
    g = MapGeometry()
    assert (g.size, g.cell) == (MAP_SIZE, MAP_CELL) == (DataConfig().map_size, DataConfig().map_cell)
    assert DataConfig().geometry == g
    assert g.half_extent == 0.5 * g.size * g.cell
    centres = g.centres()
    assert centres[g.size // 2] == 0.0 and np.allclose(np.diff(centres), g.cell)
    rec = wt.Reconstructor.load()
    assert rec.geometry == g  # the shipped model's stored run config
    for field in dataclasses.fields(DataConfig):
        if field.name in ("map_size", "map_cell"):
            assert field.default in (MAP_SIZE, MAP_CELL)
