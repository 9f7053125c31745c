"""One scan split across processes by azimuth columns gives exactly the one-process scan."""

import numpy as np
import pytest

import warp_terrain as wt
from warp_terrain.sim.parallel import ProcessHeightfields, ProcessTracer
from warp_terrain.sim.scan import trace
from warp_terrain.sim.terrain import ObstacleConfig, TerrainConfig, make_heightfields


@pytest.mark.slow
def test_processes_write_the_same_points_as_one_process():
    cfg = TerrainConfig(octaves=4, amplitude=1.5, feature_size=8.0, cell=0.1, keep_out=1.5)
    cfg.boxes = ObstacleConfig(count_min=1, count_max=3)
    cfg.pits = ObstacleConfig(count_min=1, count_max=2)
    heights = make_heightfields(2, 161, cfg, seed=3, device="cpu", obstacle_region=6.0)
    lidar = wt.lidar_preset("hdl32e", azimuth_step_deg=2.0, dropout=0.1, range_noise_std=0.02)
    single, _ = trace(heights, cfg.cell, lidar, seed=9, device="cpu", reach=7.0)
    single = single.numpy()
    with ProcessTracer(heights.numpy(), cfg.cell, lidar, seed=9, processes=2, reach=7.0) as tracer:
        for _ in range(2):  # casts repeat into the same shared memory
            points = tracer.cast()
            assert points.shape == single.shape
            assert np.array_equal(points, single, equal_nan=True)
    assert np.isfinite(single[..., 0]).mean() > 0.2


@pytest.mark.slow
def test_processes_make_the_same_heightfields_as_one_process():
    cfg = TerrainConfig(octaves=5, feature_size=6.0, cell=0.125)
    cfg.rocks = ObstacleConfig(count_min=1, count_max=3)
    cfg.pits = ObstacleConfig(count_min=1, count_max=2)
    single = make_heightfields(5, 65, cfg, seed=4, device="cpu").numpy()
    with ProcessHeightfields(5, 65, cfg, seed=4, processes=2) as terrains:
        assert np.array_equal(terrains.make(), single)
    # sample first + b is the same terrain in any batch
    tail = make_heightfields(2, 65, cfg, seed=4, device="cpu", first=3).numpy()
    assert np.array_equal(tail, single[3:])


def test_a_scan_with_a_vertical_ring_cannot_be_split():
    lidar = wt.LidarConfig(elevations_deg=[-90.0, -10.0], azimuth_step_deg=10.0)
    with pytest.raises(ValueError, match="vertical ring"):
        ProcessTracer(np.zeros((21, 21), np.float32), 0.1, lidar)
    with pytest.raises(ValueError, match="finite"):
        ProcessTracer(np.full((21, 21), np.nan, np.float32), 0.1, wt.lidar_preset("vlp16"))
