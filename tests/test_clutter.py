"""Clutter above the ground (``sim/clutter.py``, ``kernels/clutter.py``, the canopy test of the
cell walk in ``kernels/raycast.py``): exact geometry against hand-made canopy slabs, the
statistics of porous layers, reproducibility and the two targets."""

import math

import numpy as np
import pytest
import torch
import warp as wp
from conftest import tiny_sim

from warp_terrain.sim.batch import generate_batch
from warp_terrain.sim.clutter import CanopyLayer, ClutterConfig
from warp_terrain.sim.lidar import LidarConfig
from warp_terrain.sim.scan import trace

CELL = 0.25
N = 81  # vertices per side: a 20 m square, sensor on the centre vertex
MOUNT = 2.0


def flat(batch: int = 1) -> wp.array:
    return wp.zeros((batch, N, N), dtype=float, device="cpu")


def layer(bottom, top, density) -> CanopyLayer:
    """A canopy from ``(N-1, N-1)`` numpy slabs (world metres) and densities, batch 1."""
    arrays = [wp.array(np.asarray(a, dtype=np.float32)[None], dtype=float, device="cpu") for a in (bottom, top, density)]
    return CanopyLayer(*arrays)


def lidar(elevations, step: float = 1.0) -> LidarConfig:
    return LidarConfig(elevations_deg=list(elevations), azimuth_step_deg=step, min_range=0.1, max_range=100.0, range_noise_std=0.0, mount_height=MOUNT)


def cast(lid: LidarConfig, canopy=None, seed: int = 0, per_ray: bool = False) -> np.ndarray:
    points, _ = trace(flat(), CELL, lid, seed, "cpu", canopy=canopy, per_ray=per_ray)
    return wp.to_torch(points).view(-1, 3).numpy().copy()


def cell_x(i: int) -> float:
    """World x of the lower edge of cell row ``i``."""
    return (i - 0.5 * (N - 1)) * CELL


def crown_box():
    """A solid slab 3..4 m high over the cell rows whose x spans [3, 5] m, all across y."""
    i0, i1 = int(round(3.0 / CELL + 0.5 * (N - 1))), int(round(5.0 / CELL + 0.5 * (N - 1)))
    bottom = np.full((N - 1, N - 1), np.nan)
    top = np.full((N - 1, N - 1), np.nan)
    bottom[i0:i1], top[i0:i1] = 3.0, 4.0
    assert cell_x(i0) == 3.0 and cell_x(i1) == 5.0
    return bottom, top


def box_entry(d: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Ray parameter where rays from (0, 0, MOUNT) enter the box [lo, hi] (inf: miss)."""
    o = np.array([0.0, 0.0, MOUNT])
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (lo - o) / d
        t1 = (hi - o) / d
    near = np.nanmax(np.where(d == 0, np.where((o >= lo) & (o <= hi), -np.inf, np.inf), np.minimum(t0, t1)), axis=1)
    far = np.nanmin(np.where(d == 0, np.where((o >= lo) & (o <= hi), np.inf, -np.inf), np.maximum(t0, t1)), axis=1)
    return np.where((far > near) & (far > 0), np.maximum(near, 0), np.inf)


def test_solid_crown_rays_under_it_hit_the_ground_and_rays_into_it_hit_the_slab():
    lid = lidar(np.linspace(-30, 40, 15), step=3.0)
    bottom, top = crown_box()
    points = cast(lid, layer(bottom, top, np.ones_like(bottom)))
    d = lid.ray_directions().astype(np.float64)
    half = 0.5 * (N - 1) * CELL
    slab = box_entry(d, np.array([3.0, -half, 3.0]), np.array([5.0, half, 4.0]))
    with np.errstate(divide="ignore", invalid="ignore"):
        ground = np.where(d[:, 2] < 0, MOUNT / -d[:, 2], np.inf)
        ground_xy = d[:, :2] * ground[:, None]
        on_grid = np.all(np.abs(ground_xy) < half - 1e-3, axis=1)
        to_slab = np.isfinite(slab) & (slab < ground) & (np.abs(d[:, 1] * slab) < half - 1e-3)
    hit = np.isfinite(points).all(axis=1)
    to_ground = ~to_slab & np.isfinite(ground) & on_grid
    # rays that pass under (or beside) the crown meet the flat ground exactly
    assert to_ground.sum() > 100 and hit[to_ground].all()
    assert np.abs(points[to_ground, 2] + MOUNT).max() < 1e-5
    np.testing.assert_allclose(points[to_ground, :2], ground_xy[to_ground], atol=1e-3)
    # rays that meet the crown stop at its entry, within the slab
    assert to_slab.sum() > 20 and hit[to_slab].all()
    z = points[to_slab, 2] + MOUNT
    assert z.min() >= 3.0 - 1e-3 and z.max() <= 4.0 + 1e-3
    np.testing.assert_allclose(points[to_slab], d[to_slab] * slab[to_slab, None], atol=1e-3)
    # the ground under the crown is seen from the side, by rays passing beneath it
    under = to_ground & (ground_xy[:, 0] > 3.0) & (ground_xy[:, 0] < 5.0)
    assert under.sum() > 0 and np.abs(points[under, 2] + MOUNT).max() < 1e-5
    # and the crown's near face is met from the side (entries on x = 3 m between 3 and 4 m up)
    side = np.abs(points[to_slab, 0] - 3.0) < 1e-3
    assert side.sum() > 0
    # nothing else: no return where neither the ground nor the crown is on the ray's way
    assert not hit[~to_slab & ~to_ground & (np.abs(d[:, 2]) > 0.05)].any()


def test_density_zero_scans_equal_the_scan_without_clutter_bit_for_bit():
    lid = lidar(np.linspace(-30, 40, 15), step=3.0)
    bottom, top = crown_box()
    without = cast(lid, per_ray=True)
    with_transparent = cast(lid, layer(bottom, top, np.zeros_like(bottom)))
    assert np.array_equal(without, with_transparent, equal_nan=True)


def test_density_zero_config_leaves_the_batch_bit_identical():
    sim = tiny_sim()
    base = generate_batch(2, sim, seed=5, device="cpu")
    sim.terrain.clutter = ClutterConfig(enabled=True, bush_density=0.0, crown_density=0.0, grass_density=0.0)
    same = generate_batch(2, sim, seed=5, device="cpu")
    for key in ("points", "scan", "mask", "target", "scan_max"):
        assert torch.equal(getattr(base, key).nan_to_num(7.0), getattr(same, key).nan_to_num(7.0)), key
    assert same.target_visible is None and base.target_visible is None


def test_porous_grass_returns_at_its_density_per_metre():
    """A uniform 0.5 m layer over flat ground: a ray at -30 degrees crosses exactly 1 m of it
    (over several cells, each with its own draw), so it returns from the grass with probability
    ``density``; at -60 degrees it crosses 0.577 m."""
    rho = 0.35
    thick = 0.5
    shape = (N - 1, N - 1)
    canopy = layer(np.zeros(shape), np.full(shape, thick), np.full(shape, rho))
    lid = lidar([-60.0, -30.0], step=0.25)
    points = cast(lid, canopy, seed=11)
    rings = points.reshape(2, -1, 3)
    for ring, e in zip(rings, (-60.0, -30.0)):
        assert np.isfinite(ring).all()  # every ray returns: grass or ground
        z = ring[:, 2] + MOUNT
        grass = z > 1e-4
        assert z[grass].max() < thick + 1e-3  # returns within the layer: where the ray enters it over a cell
        assert np.abs(z[~grass]).max() < 1e-5
        p = 1.0 - (1.0 - rho) ** (thick / math.sin(math.radians(-e)))
        n = len(z)
        assert abs(grass.mean() - p) < 4.0 * math.sqrt(p * (1 - p) / n), (e, grass.mean(), p)


def test_clutter_scans_are_reproducible_from_the_seed_and_per_sample():
    sim = tiny_sim()
    sim.terrain.clutter = ClutterConfig(enabled=True, trees_min=1, bushes_min=2, grass_cover=0.5)
    a = generate_batch(2, sim, seed=9, device="cpu")
    b = generate_batch(2, sim, seed=9, device="cpu")
    one = generate_batch(1, sim, seed=9, device="cpu")
    other = generate_batch(2, sim, seed=10, device="cpu")
    assert torch.equal(a.points.nan_to_num(7.0), b.points.nan_to_num(7.0))
    assert torch.equal(a.target_visible, b.target_visible)
    assert torch.equal(a.points[:1].nan_to_num(7.0), one.points.nan_to_num(7.0))  # sample 0 does not depend on the batch size
    assert torch.equal(a.target_visible[:1], one.target_visible)
    assert not torch.equal(a.points.nan_to_num(7.0), other.points.nan_to_num(7.0))


def test_target_stays_the_ground_and_target_visible_is_above_it():
    sim = tiny_sim()
    base = generate_batch(2, sim, seed=4, device="cpu")
    sim.terrain.clutter = ClutterConfig(enabled=True, trees_min=2, bushes_min=3, grass_cover=0.5)
    cluttered = generate_batch(2, sim, seed=4, device="cpu")
    assert torch.equal(base.target, cluttered.target)
    assert torch.equal(base.heights, cluttered.heights)
    assert cluttered.target_visible.shape == cluttered.target.shape
    assert (cluttered.target_visible >= cluttered.target - 1e-6).all()
    assert (cluttered.target_visible > cluttered.target + 0.05).float().mean() > 0.05  # clutter is seen
    assert not torch.equal(base.points.nan_to_num(7.0), cluttered.points.nan_to_num(7.0))
    assert cluttered.to("cpu").target_visible is not None


@pytest.mark.parametrize(
    "key, value",
    [("bushes_max", -1), ("crown_lift_min", -1.0), ("crown_depth_max", 0.5), ("grass_density", 1.5), ("grass_patch", 0.0), ("enabled", "yes")],
)
def test_clutter_keys_are_checked(key, value):
    cfg = ClutterConfig(**{key: value})
    with pytest.raises(ValueError, match=rf"^clutter\.{key}\b"):
        cfg.validate("clutter")
