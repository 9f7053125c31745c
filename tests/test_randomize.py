"""The randomised world's per-batch draws: ranges honoured, one stream per batch seed."""

import copy
import functools

import pytest

from warp_terrain.compose import compose_run
from warp_terrain.sim.randomize import randomize


@functools.cache
def transfer_sim():
    """The randomised world the recipes train in (composed once: composing costs half a second;
    without looking for its Finland raster, which a clean checkout has not fetched)."""
    return compose_run(["experiment=transfer"], files=False).sim()


def randomised_sim(**ranges):
    sim = copy.deepcopy(transfer_sim())
    assert sim.data.randomize.enabled
    for key, value in ranges.items():
        setattr(sim.data.randomize, key, value)
    return sim


@pytest.mark.parametrize("seed", range(24))
def test_the_mount_height_is_drawn_in_its_range_and_widening_it_moves_nothing_else(seed):
    """A uniform draw in [lo, hi] is lo + (hi - lo) * u with u drawn from the batch's stream: widening
    the range (the tall-mount cycle, 2.5 -> 3.5 m) maps each batch's mount affinely and leaves every
    other draw of that batch (sensor, noise, octaves, obstacles, relief, ground source) as it was."""
    narrow, wide = randomised_sim(), randomised_sim(mount_height_max=3.5)
    a, amp_a, feat_a = randomize(narrow, 8, seed)
    b, amp_b, feat_b = randomize(wide, 8, seed)
    lo = narrow.data.randomize.mount_height_min
    assert lo <= a.lidar.mount_height <= 2.5 and lo <= b.lidar.mount_height <= 3.5
    assert (b.lidar.mount_height - lo) / (3.5 - lo) == pytest.approx((a.lidar.mount_height - lo) / (2.5 - lo), abs=1e-12)
    assert (amp_a == amp_b).all() and (feat_a == feat_b).all()
    b_same_mount = copy.deepcopy(b)
    b_same_mount.lidar.mount_height = a.lidar.mount_height
    b_same_mount.data.randomize = a.data.randomize
    assert b_same_mount == a


def test_a_fixed_mount_is_a_range_of_one_height():
    sim, _, _ = randomize(randomised_sim(mount_height_min=3.0, mount_height_max=3.0), 2, seed=5)
    assert sim.lidar.mount_height == 3.0
