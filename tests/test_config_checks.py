"""Every user-facing config key is checked before work starts, with a one-line error naming it.

``INVALID`` gives each leaf key of ``RunConfig`` a value that must be refused; the test walks
the schema, so a new key without an entry here (and a check in its ``validate``) fails.
``docs/configuration.md`` lists the same keys with their checks; a test keeps the two in step.
"""

from __future__ import annotations

import math
import re
from dataclasses import fields, is_dataclass
from pathlib import Path

import pytest

from warp_terrain.compose import RunConfig, to_run_config

DOC = Path(__file__).resolve().parents[1] / "docs" / "configuration.md"
OBSTACLE_INVALID = {
    "count_min": -1,
    "count_max": -1,
    "width_min": 0.0,
    "width_max": 0.1,  # below width_min
    "length_min": -2.0,
    "length_max": 1.0,  # below length_min
    "height_min": math.inf,
    "height_max": 0.2,  # below height_min
}
INVALID = {
    "terrain.name": "",
    "terrain.octaves": 0,
    "terrain.persistence": 0.0,
    "terrain.lacunarity": -2.0,
    "terrain.feature_size": 0.0,
    "terrain.amplitude": -1.0,
    "terrain.cell": 0.0,
    "terrain.margin": -1.0,
    "terrain.obstacle_region": -5.0,
    "terrain.keep_out": math.nan,
    "terrain.source": "lidar",
    "terrain.dem.files": [""],
    "terrain.dem.ground_cell": 0.0,
    "terrain.dem.nodata": "ignore",
    "terrain.dem.max_nodata": 1.0,
    "terrain.dem.scale": -1.0,
    "terrain.dem.height_scale": 0.0,
    "terrain.dem.heading": "sometimes",
    "terrain.dem.mirror": "sometimes",
    "terrain.dem.detrend": "sometimes",
    "terrain.dem.tries": 0,
    "terrain.dem.assume_metres": "sometimes",
    "terrain.clutter.enabled": "sometimes",
    "terrain.clutter.bushes_min": -1,
    "terrain.clutter.bushes_max": -1,
    "terrain.clutter.bush_radius_min": 0.0,
    "terrain.clutter.bush_radius_max": 0.1,  # below bush_radius_min
    "terrain.clutter.bush_height_min": -0.3,
    "terrain.clutter.bush_height_max": 0.1,  # below bush_height_min
    "terrain.clutter.bush_density": 1.5,
    "terrain.clutter.trees_min": -1,
    "terrain.clutter.trees_max": -1,
    "terrain.clutter.crown_radius_min": 0.0,
    "terrain.clutter.crown_radius_max": 1.0,  # below crown_radius_min
    "terrain.clutter.crown_lift_min": -2.0,
    "terrain.clutter.crown_lift_max": 1.0,  # below crown_lift_min
    "terrain.clutter.crown_depth_min": math.inf,
    "terrain.clutter.crown_depth_max": 1.0,  # below crown_depth_min
    "terrain.clutter.crown_density": -0.1,
    "terrain.clutter.grass_cover": 1.5,
    "terrain.clutter.grass_patch": 0.0,
    "terrain.clutter.grass_height_min": 0.0,
    "terrain.clutter.grass_height_max": 0.05,  # below grass_height_min
    "terrain.clutter.grass_density": math.nan,
    "terrain.tilt.enabled": "sometimes",
    "terrain.tilt.slope_min_deg": -1.0,
    "terrain.tilt.slope_max_deg": 70.0,
    "terrain.relief.enabled": "sometimes",
    "terrain.relief.octaves": 0,
    "terrain.relief.wavelength_min": 0.0,
    "terrain.relief.wavelength_max": 10.0,  # below wavelength_min
    "terrain.relief.amplitude_min": -1.0,
    "terrain.relief.amplitude_max": math.nan,
    "terrain.landforms.depressions_min": -1,
    "terrain.landforms.depressions_max": -1,
    "terrain.landforms.depression_radius_min": 0.0,
    "terrain.landforms.depression_radius_max": 1.0,  # below depression_radius_min
    "terrain.landforms.depression_depth_min": -0.5,
    "terrain.landforms.depression_depth_max": 0.1,  # below depression_depth_min
    "terrain.landforms.gullies_min": -1,
    "terrain.landforms.gullies_max": -1,
    "terrain.landforms.gully_width_min": 0.0,
    "terrain.landforms.gully_width_max": 1.0,  # below gully_width_min
    "terrain.landforms.gully_depth_min": math.inf,
    "terrain.landforms.gully_depth_max": 0.1,  # below gully_depth_min
    "terrain.landforms.gully_meander_max": -1.0,
    "terrain.landforms.gully_wavelength_min": 0.0,
    "terrain.landforms.gully_wavelength_max": 5.0,  # below gully_wavelength_min
    "terrain.landforms.terrace_probability": 1.5,
    "terrain.landforms.terrace_rise_min": 0.0,
    "terrain.landforms.terrace_rise_max": 0.1,  # below terrace_rise_min
    "terrain.landforms.terrace_tread_min": -0.1,
    "terrain.landforms.terrace_tread_max": 0.95,
    **{f"terrain.{kind}.{k}": v for kind in ("cylinders", "boxes", "rocks", "pits", "ditches") for k, v in OBSTACLE_INVALID.items()},
    "lidar.name": "",
    "lidar.elevations_deg": [],
    "lidar.azimuth_step_deg": 0.0,
    "lidar.azimuth_start_deg": math.nan,
    "lidar.fov_deg": 400.0,
    "lidar.min_range": -1.0,
    "lidar.max_range": 0.01,  # below min_range
    "lidar.range_noise_std": -0.1,
    "lidar.dropout": 1.0,
    "lidar.mount_height": 0.0,
    "data.map_size": 0,
    "data.map_cell": -0.25,
    "data.noise": 1.5,
    "data.augment": "sometimes",
    "data.truth_samples": 0,
    "data.fill": math.inf,
    "data.clip_rays": "sometimes",
    "data.randomize.enabled": "sometimes",
    "data.randomize.amplitude_min": 0.0,
    "data.randomize.amplitude_max": 0.01,  # below amplitude_min
    "data.randomize.feature_size_min": -3.0,
    "data.randomize.feature_size_max": 1.0,  # below feature_size_min
    "data.randomize.octaves_min": 0,
    "data.randomize.octaves_max": 17,
    "data.randomize.lidars": ["hdl32e", "no-such-lidar"],
    "data.randomize.mount_height_min": 0.0,
    "data.randomize.mount_height_max": 1.0,  # below mount_height_min
    "data.randomize.range_noise_max": 1.0,
    "data.randomize.obstacle_probability": 1.5,
    "data.randomize.obstacle_probabilities": {"pits": 1.5},
    "data.randomize.azimuth_step_min_deg": -0.1,
    "data.randomize.noise_max": -0.5,
    "data.randomize.dem_probability": 1.5,
    "data.randomize.plain_probability": -0.1,
    "scans.files": [""],
    "scans.share": 1.5,
    "scans.hide_min": 0.0,
    "scans.hide_max": 1.0,
    "scans.blob_probability": -0.1,
    "scans.blob_cells": 0.5,
    "scans.shift_m": -1.0,
    "model.name": "resnet",
    "model.in_channels": 3,
    "model.out_channels": 2,
    "model.ngf": 0,
    "model.ndf": -4,
    "model.disc_layers": 0,
    "model.unet_depth": 1,
    "model.refine": -1,
    "model.norm": "layer",
    "model.dropout": 1.0,
    "model.gan_mode": "wgan",
    "model.lambda_l1": -1.0,
    "model.height_loss": "l3",
    "model.lr_g": 0.0,
    "model.lr_d": -1e-4,
    "model.beta1": 1.0,
    "model.beta2": -0.1,
    "model.residual": "sometimes",
    "model.unobserved_weight": 0.0,
    "model.height_scale_min": -0.05,
    "model.uncertainty": "maybe",
    "model.relief_relative_loss": "often",
    "model.base_fill": "kriging",
    "model.height_reference": "median",
    "model.observed_bound": -0.1,
    "model.observed_bound_noise": -1.0,
    "model.screened_input": -0.1,
    "model.start_from_fill": "maybe",
    "model.fill_relative_loss": "maybe",
    "model.centre_cells": "maybe",
    "model.fill_relative_statistic": "mode",
    "train.steps": 0,
    "train.batch_size": 0,
    "train.val_every": 0,
    "train.val_size": 0,
    "train.log_every": 0,
    "train.image_every": 0,
    "train.checkpoint_every": 0,
    "train.resume": "/no/such/run/checkpoints/latest.pt",
    "train.workers": -1,
    "train.prefetch": 0,
    "train.device": "tpu",
    "train.seed": -1,
    "train.lr_decay_from": 1.5,
    "train.threads": -2,
    "train.progress": "sometimes",
    "train.dataset": "/no/such/dataset",
    "train.capture": "sometimes",
    "train.init_from": "/no/such/model.pt",
    "train.cell_dropout": 1.0,
}
# Free text, recorded with a preset and never interpreted: nothing can be wrong with it.
UNCHECKED = {"lidar.source"}


def leaf_keys(node, prefix: str = "") -> list[str]:
    keys = []
    for f in fields(node):
        value = getattr(node, f.name)
        if is_dataclass(value):
            keys += leaf_keys(value, f"{prefix}{f.name}.")
        else:
            keys.append(prefix + f.name)
    return keys


def nested(key: str, value) -> dict:
    out = value
    for part in reversed(key.split(".")):
        out = {part: out}
    return out


def test_every_key_has_an_invalid_value_or_is_declared_free_text():
    keys = set(leaf_keys(RunConfig()))
    assert keys == set(INVALID) | UNCHECKED, (sorted(keys - set(INVALID) - UNCHECKED), sorted(set(INVALID) - keys))


def test_defaults_are_valid():
    to_run_config(RunConfig())
    to_run_config({"data": {"randomize": {"enabled": True}}})


@pytest.mark.parametrize("key", sorted(INVALID))
def test_invalid_value_is_refused_naming_the_key(key):
    with pytest.raises(ValueError) as info:
        to_run_config(nested(key, INVALID[key]))
    message = str(info.value)
    assert "\n" not in message, message
    assert message.startswith(key), f"{key}: {message}"


@pytest.mark.parametrize(
    "override, key",
    [
        ({"model": {"name": "paper"}, "data": {"map_size": 64}}, "data.map_size"),
        ({"model": {"residual": True, "in_channels": 1}}, "model.residual"),
        ({"model": {"relief_relative_loss": True}}, "model.relief_relative_loss"),
        ({"model": {"residual": False, "in_channels": 2, "start_from_fill": True}}, "model.start_from_fill"),
        ({"terrain": {"keep_out": 16.0, "cylinders": {"count_min": 1, "count_max": 2}}}, "terrain.keep_out"),
        ({"terrain": {"keep_out": 3.0, "obstacle_region": 2.0, "pits": {"count_max": 1}}}, "terrain.keep_out"),
        ({"terrain": {"source": "dem"}}, "terrain.dem.files=[]: give at least one raster"),
        ({"terrain": {"source": "dem", "dem": {"files": ["/no/such/dem.tif"]}}}, "terrain.dem.files[0]='/no/such/dem.tif': no such file"),
        ({"scans": {"share": 0.5}}, "scans.files=[]: share=0.5 mixes in real scans"),
        ({"scans": {"hide_min": 0.3, "hide_max": 0.2}}, "scans.hide_max=0.2"),
    ],
)
def test_inconsistent_keys_are_refused(override, key):
    with pytest.raises(ValueError) as info:
        to_run_config(override)
    assert str(info.value).startswith(key), str(info.value)
    assert "\n" not in str(info.value)


def test_unknown_key_is_refused_naming_it():
    with pytest.raises(ValueError, match=r"^terrain\.octave\b"):
        to_run_config({"terrain": {"octave": 3}})


def test_the_docs_table_lists_every_key():
    documented = set(re.findall(r"^\| `([a-z0-9_.]+(?:\{[a-z,]+\})?[a-z0-9_.]*)` \|", DOC.read_text(encoding="utf-8"), flags=re.M))
    expanded = set()
    for key in documented:
        match = re.fullmatch(r"(.*)\{([a-z,]+)\}(.*)", key)
        expanded |= {f"{match[1]}{k}{match[3]}" for k in match[2].split(",")} if match else {key}
    assert expanded == set(leaf_keys(RunConfig())), (sorted(set(leaf_keys(RunConfig())) - expanded), sorted(expanded - set(leaf_keys(RunConfig()))))
