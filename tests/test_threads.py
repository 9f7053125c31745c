"""CPU launches split over threads (``sim/threads.py``): the same result as one launch, bit for bit."""

import numpy as np
import pytest

import warp_terrain as wt
from warp_terrain.sim import threads as threads_module
from warp_terrain.sim.scan import THREAD_MIN_RAYS
from warp_terrain.sim.threads import run_parts, split_threads


@pytest.mark.parametrize("threads", [2, 3, 7])
def test_a_scan_split_over_threads_equals_one_launch(threads):
    """Range noise, dropout and the per-ray seeds follow the ray, not the thread: every point of
    two scans (odd column counts per thread included) is bit-identical to the one-launch cast."""
    heights = wt.fractal_heightfield(2, 97, 0.2, feature_size=6.0, amplitude=1.5, seed=4, device="cpu")
    lidar = wt.lidar_preset("vlp16", azimuth_step_deg=1.7, range_noise_std=0.02, dropout=0.1)
    one = wt.cast_scans(heights, 0.2, lidar, seed=3, device="cpu", threads=1).numpy()
    split = wt.cast_scans(heights, 0.2, lidar, seed=3, device="cpu", threads=threads).numpy()
    assert 0.15 < np.isfinite(one[..., 0]).mean() < 0.9  # hits, misses and drops: measured 0.24
    np.testing.assert_array_equal(split, one)


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_bad_thread_counts_are_refused_by_name(bad):
    heights = np.zeros((9, 9), dtype=np.float32)
    with pytest.raises(ValueError, match="threads"):
        wt.cast_scans(heights, 0.5, wt.lidar_preset("vlp16"), device="cpu", threads=bad)


def test_how_many_threads_a_launch_gets(monkeypatch):
    monkeypatch.setattr(threads_module, "usable_cores", lambda: 4)
    assert split_threads(None, 10 * THREAD_MIN_RAYS, THREAD_MIN_RAYS, "cpu") == 4  # enough work for every core
    assert split_threads(None, 2 * THREAD_MIN_RAYS, THREAD_MIN_RAYS, "cpu") == 2  # each thread gets min_work
    assert split_threads(None, 2 * THREAD_MIN_RAYS - 1, THREAD_MIN_RAYS, "cpu") == 1
    assert split_threads(None, 10, THREAD_MIN_RAYS, "cpu") == 1
    assert split_threads(3, 10, THREAD_MIN_RAYS, "cpu") == 3  # asked for: given, small work or not
    assert split_threads(8, 5, THREAD_MIN_RAYS, "cpu") == 5  # never more threads than elements
    assert split_threads(4, 10 * THREAD_MIN_RAYS, THREAD_MIN_RAYS, "cuda:0") == 1  # one launch fills a GPU
    assert split_threads(None, 10 * THREAD_MIN_RAYS, THREAD_MIN_RAYS, "cuda:0") == 1


def test_run_parts_runs_every_part_once_and_reraises():
    seen = []
    run_parts(seen.append, [3, 1, 2])
    assert sorted(seen) == [1, 2, 3]

    def fail(part):
        if part == 2:
            raise RuntimeError("part 2 failed")

    with pytest.raises(RuntimeError, match="part 2 failed"):
        run_parts(fail, [0, 1, 2])


@pytest.mark.parametrize("threads", [2, 3])
def test_heightfields_split_over_threads_equal_one_launch(threads):
    """Sample ``b`` depends only on ``(seed, b)``: seven fields made by 2 or 3 threads (uneven
    parts) are the one-launch fields, bit for bit."""
    one = wt.fractal_heightfield(7, 49, 0.25, feature_size=4.0, seed=11, device="cpu", threads=1).numpy()
    split = wt.fractal_heightfield(7, 49, 0.25, feature_size=4.0, seed=11, device="cpu", threads=threads).numpy()
    assert float(np.abs(one).max()) > 0.1  # real fields
    np.testing.assert_array_equal(split, one)
    with pytest.raises(ValueError, match="threads"):
        wt.fractal_heightfield(2, 9, 0.5, device="cpu", threads=0)
