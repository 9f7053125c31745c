"""Kernel switches (``sim/switches.py``): every variant gives the default's output bit for bit,
and each switch really selects its variant."""

import numpy as np
import pytest
import torch
import warp as wp

import warp_terrain as wt
from warp_terrain.kernels import raycast as raycast_kernels
from warp_terrain.sim import terrain as terrain_module
from warp_terrain.sim.scan import trace
from warp_terrain.sim.switches import KernelSwitches, kernel_switches, use_kernel_switches
from warp_terrain.sim.terrain import TerrainConfig, make_heightfields

COLUMN_VARIANTS = [dict(static_tile=True), dict(deferred_writes=True), dict(static_tile=True, deferred_writes=True)]


def noisy_lidar() -> wt.LidarConfig:
    return wt.lidar_preset("vlp16", range_noise_std=0.03, dropout=0.2)


@pytest.fixture(scope="module")
def terrain() -> torch.Tensor:
    cfg = TerrainConfig(amplitude=1.5, feature_size=6.0, cell=0.25)
    cfg.cylinders.count_min = cfg.cylinders.count_max = 4
    return wp.to_torch(make_heightfields(2, 121, cfg, 3, "cpu"))


def test_switches_are_scoped_checked_and_named():
    assert kernel_switches() == KernelSwitches()
    with use_kernel_switches(deferred_writes=True) as outer:
        assert kernel_switches() is outer and outer.deferred_writes and not outer.static_tile
        with use_kernel_switches(static_tile=True):
            assert kernel_switches() == KernelSwitches(static_tile=True, deferred_writes=True)  # on top of the outer block
        assert kernel_switches() is outer
    assert kernel_switches() == KernelSwitches()
    with pytest.raises(ValueError, match="unknown deferred"):
        with use_kernel_switches(deferred=True):
            pass
    with pytest.raises(ValueError, match="static_tile: must be one of"):
        with use_kernel_switches(static_tile=1):
            pass
    with pytest.raises(ValueError, match="deferred_writes: must be one of"):
        with use_kernel_switches(deferred_writes=None):  # only the fBm switch has an automatic choice
            pass
    assert kernel_switches() == KernelSwitches()
    assert KernelSwitches().fbm_table_on("cpu") and not KernelSwitches().fbm_table_on("cuda:0")
    assert KernelSwitches(fbm_table=True).fbm_table_on("cuda:0") and not KernelSwitches(fbm_table=False).fbm_table_on("cpu")


@pytest.mark.parametrize("variant", COLUMN_VARIANTS, ids=lambda v: "+".join(v))
@pytest.mark.parametrize("threads", [1, 3])
def test_column_walk_variants_give_the_same_points_bit_for_bit(terrain, variant, threads):
    lidar = noisy_lidar()
    reference = wt.cast_scans(terrain, 0.25, lidar, seed=11, device="cpu", threads=1).numpy()
    assert 0.1 < np.isnan(reference[..., 0]).mean() < 0.9  # returns, misses and dropouts alike
    with use_kernel_switches(**variant):
        points = wt.cast_scans(terrain, 0.25, lidar, seed=11, device="cpu", threads=threads).numpy()
    np.testing.assert_array_equal(points, reference)


def test_each_column_switch_launches_its_own_kernel(terrain, monkeypatch):
    launched = []
    launch = wp.launch

    def spy(kernel, *args, **kwargs):
        launched.append(kernel)
        return launch(kernel, *args, **kwargs)

    monkeypatch.setattr(wp, "launch", spy)
    for variant in [{}, *COLUMN_VARIANTS]:
        launched.clear()
        with use_kernel_switches(**variant):
            wt.cast_scans(terrain, 0.25, noisy_lidar(), device="cpu", threads=1)
        walk = raycast_kernels.column_kernel(variant.get("static_tile", False), variant.get("deferred_writes", False))
        assert walk in launched
        assert (raycast_kernels.write_returns in launched) == variant.get("deferred_writes", False)
    assert raycast_kernels.column_kernel() is raycast_kernels.cast_columns
    assert len({raycast_kernels.column_kernel(s, d) for s in (False, True) for d in (False, True)}) == 4


def test_deferred_writes_touch_only_the_columns_walked(terrain):
    """``sim/parallel.py`` casts a share of a scan's columns into a shared output: the deferred
    pass must write those columns' rays and no other."""
    lidar = noisy_lidar()
    heights = wp.from_torch(terrain.contiguous())
    columns = lidar.num_rays // lidar.channels
    full, _ = trace(heights, 0.25, lidar, 4, "cpu")
    share = range(1, columns, 3)
    sentinel = np.full((2, lidar.num_rays, 3), 123.0, dtype=np.float32)
    with use_kernel_switches(deferred_writes=True):
        out = wp.array(sentinel, dtype=wp.vec3, device="cpu")
        trace(heights, 0.25, lidar, 4, "cpu", columns=share, out=out)
    walked = np.zeros(lidar.num_rays, dtype=bool)
    walked[(np.arange(lidar.num_rays) % columns) % 3 == 1] = True
    np.testing.assert_array_equal(out.numpy()[:, walked], full.numpy()[:, walked])
    assert np.all(out.numpy()[:, ~walked] == 123.0)


def test_fbm_switch_picks_the_path_and_both_paths_agree(monkeypatch):
    cfg = TerrainConfig(octaves=5, feature_size=8.0, amplitude=1.5, cell=0.25)
    table = make_heightfields(2, 97, cfg, 5, "cpu").numpy()
    calls = []
    rows = terrain_module.fbm_rows
    monkeypatch.setattr(terrain_module, "fbm_rows", lambda *a, **k: (calls.append(1), rows(*a, **k))[1])
    with use_kernel_switches(fbm_table=False):
        per_vertex = make_heightfields(2, 97, cfg, 5, "cpu").numpy()
    assert calls == []  # wp.noise per vertex: the lattice-gradient path did not run
    make_heightfields(2, 97, cfg, 5, "cpu")
    assert calls == [1]  # the CPU's default is the lattice-gradient path
    np.testing.assert_allclose(table, per_vertex, rtol=0, atol=1e-6 * cfg.amplitude)
    assert np.abs(table).max() > 0.5


def test_a_batch_is_the_same_under_every_switch():
    sim = wt.SimConfig()
    sim.lidar = noisy_lidar()
    sim.data.noise = 0.05
    sim.terrain.margin = 0.5
    reference = wt.generate_batch(2, sim, seed=9, device="cpu")
    with use_kernel_switches(static_tile=True, deferred_writes=True):
        other = wt.generate_batch(2, sim, seed=9, device="cpu")
    for key in ("heights", "points", "scan", "mask", "scan_max", "target"):
        np.testing.assert_array_equal(getattr(other, key).numpy(), getattr(reference, key).numpy(), err_msg=key)
