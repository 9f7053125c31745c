"""Shared test helpers: the repository root, a tiny simulator setting and a tiny training run.

Test modules import the plain helpers (``from conftest import TINY_RUN, run_config, tiny_sim``);
pytest puts this folder on ``sys.path``.
"""

import os

os.environ.setdefault("WARP_TERRAIN_VERBOSE", "")
# Every test runs on the CPU unless it asks for CUDA by name (and is marked ``gpu``): calls that
# leave ``device=None`` would otherwise pick CUDA on a GPU machine and then call ``.numpy()``.
os.environ["WARP_TERRAIN_DEVICE"] = "cpu"

from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402
import warp as wp  # noqa: E402

import warp_terrain  # noqa: E402, F401  (sets Warp's log level before any kernel loads)
from warp_terrain.compose import compose_run  # noqa: E402
from warp_terrain.sim import SimConfig, lidar_preset  # noqa: E402
from warp_terrain.sim.device import init_warp  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

#: a small and quick run: 41x41 maps (so the generic U-Net), a sparse sensor, narrow nets
TINY_RUN = [
    "model=unet",
    "model.ngf=8",
    "model.ndf=8",
    "model.unet_depth=3",
    "data.map_size=41",
    "terrain.margin=0.5",
    "lidar=vlp16",
    "lidar.azimuth_step_deg=2.0",
    "train.batch_size=2",
    "train.val_size=4",
    "train.log_every=1",
    "train.workers=0",
    "train.progress=false",
]


def run_config(*overrides):
    """The validated ``RunConfig`` that ``python train.py OVERRIDES`` would run."""
    return compose_run(list(overrides))


def tiny_sim(noise: float = 0.0) -> SimConfig:
    """41 x 41 maps, the VLP-16 at a 2-degree azimuth step, a thin terrain margin."""
    sim = SimConfig(lidar=lidar_preset("vlp16", azimuth_step_deg=2.0))
    sim.data.map_size = 41
    sim.terrain.margin = 0.5
    sim.data.noise = noise
    return sim


def pytest_collection_modifyitems(config, items):
    """Tests marked ``gpu`` need CUDA: skipped on a machine without it."""
    init_warp()
    if wp.is_cuda_available() and torch.cuda.is_available():
        return
    skip = pytest.mark.skip(reason="needs a CUDA device (marked gpu)")
    for item in items:
        if "gpu" in item.keywords:
            item.add_marker(skip)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
