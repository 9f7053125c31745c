import os

os.environ.setdefault("WARP_TERRAIN_VERBOSE", "")

import numpy as np
import pytest

import warp_terrain  # noqa: F401  (sets Warp's log level before any kernel loads)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
