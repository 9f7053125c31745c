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


@pytest.mark.parametrize("seed", range(24))
def test_a_kind_of_obstacle_can_be_made_more_likely_without_moving_any_other_draw(seed):
    """Each kind's uniform is drawn from the batch's stream whatever its threshold: raising the
    pits' and ditches' probability (the negative-obstacle world) adds those kinds to some batches
    and leaves every other draw of each batch as it was; 1 and 0 are always and never."""
    base = randomised_sim()
    p = base.data.randomize.obstacle_probability
    a, amp_a, feat_a = randomize(base, 8, seed)
    b, amp_b, feat_b = randomize(randomised_sim(obstacle_probabilities={"pits": 0.9, "ditches": 0.9}), 8, seed)
    assert (amp_a == amp_b).all() and (feat_a == feat_b).all()
    for kind in ("pits", "ditches"):
        if getattr(a.terrain, kind).count_max > 0:  # drawn under p, so also under 0.9 > p
            assert getattr(b.terrain, kind) == getattr(a.terrain, kind)
    b_same = copy.deepcopy(b)
    b_same.terrain.pits, b_same.terrain.ditches = a.terrain.pits, a.terrain.ditches
    b_same.data.randomize = a.data.randomize
    assert b_same == a
    always, _, _ = randomize(randomised_sim(obstacle_probabilities={"pits": 1.0}), 8, seed)
    never, _, _ = randomize(randomised_sim(obstacle_probabilities={"pits": 0.0}), 8, seed)
    assert always.terrain.pits.count_min >= 1 and never.terrain.pits.count_max == 0
    assert p == 0.4  # the recipes' default the other kinds keep


def test_the_pits_and_ditches_share_follows_their_probability():
    sim = randomised_sim(obstacle_probabilities={"pits": 0.8})
    draws = [randomize(sim, 1, seed)[0].terrain for seed in range(400)]
    pits = sum(t.pits.count_max > 0 for t in draws) / len(draws)
    rocks = sum(t.rocks.count_max > 0 for t in draws) / len(draws)
    assert 0.74 < pits < 0.86 and 0.33 < rocks < 0.47  # binomial(400): 3.5 standard deviations


@pytest.mark.parametrize(
    ("value", "message"),
    [({"craters": 0.5}, "unknown obstacle kind"), ({"pits": 1.5}, "must be in \\[0, 1\\]"), ({"pits": float("nan")}, "must be finite")],
)
def test_a_bad_obstacle_probability_is_named(value, message):
    sim = randomised_sim(obstacle_probabilities=value)
    with pytest.raises(ValueError, match=message):
        sim.data.randomize.validate()
