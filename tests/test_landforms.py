"""Tilt, low-frequency relief, depressions, gullies, terraces and dense obstacles
(``kernels/landforms.py``, ``sim/landforms.py``): exact geometry where it allows, defaults
bit-identical to the terrain before these existed, reproducible from the seed."""

from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest
import torch
import warp as wp
from conftest import tiny_sim

import warp_terrain as wt
from warp_terrain.compose import compose_run
from warp_terrain.kernels import landforms as lk
from warp_terrain.sim import memory
from warp_terrain.sim.landforms import LandformConfig, ReliefConfig, TiltConfig, draw_landforms
from warp_terrain.sim.presets import preset_sim, terrain_preset, terrain_preset_names
from warp_terrain.sim.terrain import OBSTACLE_KINDS, ObstacleConfig, TerrainConfig, grid_size, make_heightfields, scratch_bytes

CELL = 0.125


def flat(**groups) -> TerrainConfig:
    """Flat fBm (amplitude 0) with the given landform groups."""
    return TerrainConfig(octaves=1, amplitude=0.0, **groups)


def positions(n: int, cell: float) -> np.ndarray:
    return (np.arange(n) - 0.5 * (n - 1)) * cell


# ------------------------------------------------------------------ tilt
def test_tilt_gives_a_target_with_exactly_that_slope_and_the_drawn_direction():
    sim = tiny_sim()
    sim.data.augment = False
    sim.terrain = flat(tilt=TiltConfig(enabled=True, slope_min_deg=20.0, slope_max_deg=20.0))
    sim.terrain.margin = 0.5
    batch = wt.generate_batch(3, sim, seed=11, device="cpu")
    drawn = draw_landforms(3, batch.heights.shape[1], sim.terrain.cell, sim.terrain.tilt, sim.terrain.relief,
                           sim.terrain.landforms, 11, "cpu").params.numpy()["gradient"]
    x = positions(sim.data.map_size, sim.data.map_cell)
    X, Y = np.meshgrid(x, x, indexing="ij")
    A = np.stack([X.ravel(), Y.ravel(), np.ones(X.size)], axis=1)
    for b in range(3):
        target = batch.target[b, 0].double().numpy()
        (gx, gy, _), *_ = np.linalg.lstsq(A, target.ravel(), rcond=None)
        assert math.hypot(gx, gy) == pytest.approx(math.tan(math.radians(20.0)), abs=2e-5)
        assert (gx, gy) == pytest.approx(tuple(drawn[b]), abs=2e-5)
        plane = A @ np.array([gx, gy, 0.0])
        assert np.abs(target.ravel() - target.ravel().mean() - (plane - plane.mean())).max() < 1e-4  # a plane
    directions = np.arctan2(drawn[:, 1], drawn[:, 0])
    assert len(np.unique(np.round(directions, 3))) == 3  # a random direction per sample


def test_tilt_slope_is_drawn_within_its_range():
    tilt = TiltConfig(enabled=True, slope_min_deg=10.0, slope_max_deg=30.0)
    g = draw_landforms(256, 65, CELL, tilt, ReliefConfig(), LandformConfig(), 3, "cpu").params.numpy()["gradient"]
    slopes = np.degrees(np.arctan(np.hypot(g[:, 0], g[:, 1])))
    assert slopes.min() >= 10.0 - 1e-3 and slopes.max() <= 30.0 + 1e-3
    assert slopes.min() < 13.0 and slopes.max() > 27.0


# ------------------------------------------------------------------ low-frequency relief
def test_relief_is_bounded_by_its_amplitude_and_low_frequency():
    relief = ReliefConfig(enabled=True, octaves=2, wavelength_min=60.0, wavelength_max=60.0, amplitude_min=7.0, amplitude_max=7.0)
    n = grid_size(32.0, CELL)
    h = make_heightfields(8, n, flat(relief=relief), 5, "cpu").numpy()
    assert np.abs(h).max() <= 7.0 + 1e-4
    spans = h.max(axis=(1, 2)) - h.min(axis=(1, 2))
    assert spans.max() > 2.0  # metres of relief across the map
    step = np.abs(np.diff(h, axis=1)).max() / CELL
    assert step < 2.0  # smooth: no fine detail at 60 m wavelength


# ------------------------------------------------------------------ depressions and gullies
def one_cut(depression=None, gully=None, n: int = 97) -> np.ndarray:
    depressions = wp.array([depression or lk.Depression()], dtype=lk.Depression, device="cpu").reshape((1, 1))
    gullies = wp.array([gully or lk.Gully()], dtype=lk.Gully, device="cpu").reshape((1, 1))
    heights = wp.zeros((1, n, n), dtype=float, device="cpu")
    wp.launch(lk.carve, dim=heights.shape, inputs=[depressions, gullies, CELL], outputs=[heights], device="cpu")
    return heights.numpy()[0]


def test_a_depression_has_its_minimum_at_its_centre_with_its_depth():
    d = lk.Depression()
    d.center = wp.vec2(1.0, -2.0)
    d.radius = 4.0
    d.depth = 1.5
    h = one_cut(depression=d)
    x = positions(h.shape[0], CELL)
    i, j = np.unravel_index(np.argmin(h), h.shape)
    assert (x[i], x[j]) == (1.0, -2.0)
    assert h[i, j] == pytest.approx(-1.5, abs=1e-6)
    X, Y = np.meshgrid(x, x, indexing="ij")
    r = np.hypot(X - 1.0, Y + 2.0)
    assert np.all(h[r >= 4.0] == 0.0)  # closed: level beyond the rim
    assert np.allclose(h, -1.5 * np.clip(1 - (r / 4.0) ** 2, 0, None) ** 2, atol=1e-6)


def test_a_drawn_depression_on_flat_ground_reaches_its_depth_at_its_centre():
    forms = LandformConfig(depressions_min=1, depressions_max=1, depression_radius_min=5.0, depression_radius_max=5.0,
                           depression_depth_min=1.0, depression_depth_max=2.0)
    n = grid_size(32.0, CELL)
    cfg = flat(landforms=forms)
    h = make_heightfields(4, n, cfg, 2, "cpu").numpy()
    drawn = draw_landforms(4, n, CELL, cfg.tilt, cfg.relief, forms, 2, "cpu").depressions.numpy()[:, 0]
    x = positions(n, CELL)
    for b in range(4):
        i, j = np.unravel_index(np.argmin(h[b]), h[b].shape)
        assert math.hypot(x[i] - drawn["center"][b][0], x[j] - drawn["center"][b][1]) <= CELL
        depth = float(drawn["depth"][b])
        assert h[b].min() == pytest.approx(-depth, abs=depth * 2 * (CELL / 5.0) ** 2)


@pytest.mark.parametrize("shape", [0.0, 1.0])
def test_a_straight_gully_has_its_cross_section(shape):
    g = lk.Gully()
    g.center = wp.vec2(0.0, 0.0)
    g.heading = 0.0  # along x
    g.half_width = 2.0
    g.depth = 1.0
    g.meander = 0.0
    g.wavenumber = 1.0
    g.phase = 0.0
    g.shape = shape
    h = one_cut(gully=g)
    y = positions(h.shape[0], CELL)
    t = np.abs(y) / 2.0
    smooth = lambda v: np.clip(v, 0, 1) ** 2 * (3 - 2 * np.clip(v, 0, 1))  # noqa: E731
    profile = 1 - smooth(t) if shape == 0.0 else 1 - smooth(2 * t - 1)
    assert np.allclose(h, -np.broadcast_to(profile, h.shape), atol=1e-6)  # the same at every x
    assert h[0, np.argmin(np.abs(y))] == pytest.approx(-1.0, abs=1e-6)
    if shape == 1.0:
        assert np.all(h[:, np.abs(y) <= 1.0] == pytest.approx(-1.0, abs=1e-6))  # U: a flat floor


# ------------------------------------------------------------------ terraces
def terrace(h: np.ndarray, rise: float, tread: float, phase: float) -> np.ndarray:
    params = lk.SampleLandforms()
    params.terrace_rise = rise
    params.terrace_tread = tread
    params.terrace_phase = phase
    heights = wp.array(h[None].astype(np.float32), dtype=float, device="cpu")
    wp.launch(lk.add_terraces, dim=heights.shape, inputs=[wp.array([params], dtype=lk.SampleLandforms, device="cpu")],
              outputs=[heights], device="cpu")
    return heights.numpy()[0]


def test_terraces_on_a_ramp_step_by_the_rise():
    ramp = np.tile(np.linspace(0.0, 5.0, 2001)[:, None], (1, 3))
    out = terrace(ramp, rise=0.5, tread=0.4, phase=0.0)
    u = ramp / 0.5
    k = np.floor(u)
    f = np.clip((u - k - 0.4) / 0.6, 0, 1)
    assert np.allclose(out, 0.5 * (k + f * f * (3 - 2 * f)), atol=1e-5)
    treads = out[(u - k) < 0.4 - 1e-3]  # the flat part of every step
    levels = np.unique(np.round(treads, 4))
    assert np.allclose(levels, 0.5 * np.arange(len(levels)), atol=1e-4) and len(levels) == 11  # 0, 0.5, ..., 5
    assert np.all(np.diff(out[:, 0]) >= -1e-6)  # still a ramp up
    assert np.abs(out - ramp).max() <= 0.5


def test_terraces_without_tread_are_the_smoothstep_quantiser():
    ramp = np.linspace(-2.0, 3.0, 501)[:, None]
    out = terrace(ramp, rise=0.8, tread=0.0, phase=0.0)
    frac = ramp / 0.8 - np.floor(ramp / 0.8)
    assert np.allclose(out, 0.8 * (np.floor(ramp / 0.8) + frac * frac * (3 - 2 * frac)), atol=1e-5)


# ------------------------------------------------------------------ obstacles
def test_forty_cylinders_are_all_stamped():
    cfg = flat(cylinders=ObstacleConfig(count_min=40, count_max=40, width_min=0.3, width_max=0.3, height_min=0.5, height_max=3.0))
    h = make_heightfields(2, grid_size(32.0, CELL), cfg, 4, "cpu", obstacle_region=15.0).numpy()
    for b in range(2):
        tops = np.unique(h[b][h[b] > 0])  # each cylinder's own flat top
        assert len(tops) == 40


# ------------------------------------------------------------------ defaults, seeds, the preset, memory
# sha256 of (heights, target) of tiny_sim batches (3, seed 7, cpu) made by the code before landforms existed
GOLDEN = {
    "octave5": "530727f6444a77584676f905b34444c224c117c9a9d9586e536a8798d91dab67",
    "flat_cylinders": "2caca2c4310a991789fdafc683d119e409d25f7e6a11aaca549dff3995100786",
}


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_defaults_are_bit_identical_to_the_terrain_before_landforms(name):
    sim = tiny_sim()
    sim.terrain = terrain_preset(name)
    sim.terrain.margin = 0.5
    batch = wt.generate_batch(3, sim, seed=7, device="cpu")
    digest = hashlib.sha256()
    for key in ("heights", "target"):
        digest.update(np.ascontiguousarray(getattr(batch, key).numpy()).tobytes())
    assert digest.hexdigest() == GOLDEN[name]
    # groups present but off, with other ranges: still the same batch
    sim.terrain.tilt = TiltConfig(enabled=False, slope_min_deg=5.0, slope_max_deg=9.0)
    sim.terrain.relief = ReliefConfig(enabled=False, amplitude_min=3.0)
    sim.terrain.landforms = LandformConfig(terrace_rise_min=0.9)
    again = wt.generate_batch(3, sim, seed=7, device="cpu")
    assert torch.equal(batch.heights, again.heights) and torch.equal(batch.target, again.target)


def test_landforms_are_reproducible_from_the_seed_and_independent_of_the_batch():
    cfg = terrain_preset("wide")
    n = grid_size(20.0, CELL)
    a = make_heightfields(3, n, cfg, 9, "cpu").numpy()
    assert np.array_equal(a, make_heightfields(3, n, cfg, 9, "cpu").numpy())
    assert np.array_equal(a[1:], make_heightfields(2, n, cfg, 9, "cpu", first=1).numpy())
    assert not np.array_equal(a, make_heightfields(3, n, cfg, 10, "cpu").numpy())


def test_the_wide_preset_validates_composes_and_generates():
    sim = preset_sim("wide")
    batch = wt.generate_batch(4, sim, seed=0)
    assert torch.isfinite(batch.target).all() and torch.isfinite(batch.heights).all()
    assert "wide" not in terrain_preset_names()  # ``all`` stays the paper's settings
    run = compose_run(["terrain=wide"])
    assert run.terrain.tilt.enabled and run.terrain.relief.enabled and run.terrain.landforms.enabled()
    assert [getattr(run.terrain, kind).count_max for kind in OBSTACLE_KINDS] == [30, 12, 30, 12, 6]  # up to 90 obstacles
    assert run.terrain.clutter.enabled and batch.target_visible is not None


def test_the_memory_estimate_counts_the_terrain_scratch():
    sim = preset_sim("wide")
    size = wt.sim.batch.terrain_size(sim)
    rays, maps = sim.lidar.num_rays, sim.data.map_size
    scratch = scratch_bytes(sim.terrain)
    assert 90 * 28 <= scratch < 64 * 1024  # dozens of obstacles are a few kB per sample
    # freed before the scan allocates, so the estimate stands for the wide world as it is
    assert memory.batch_bytes(2, size, rays, maps, scratch) == memory.batch_bytes(2, size, rays, maps)
    assert memory.batch_bytes(2, size, rays, maps, 10**9) == 2 * (4 * size**2 + 10**9)


def test_plain_probability_turns_a_batchs_landforms_off_and_leaves_every_other_draw():
    """``data.randomize.plain_probability``: that share of the wide world's batches has tilt,
    relief and landforms off (plain fBm); the sensor, noise, obstacle and relief draws are those
    of the same seed without the mix, and a batch that is not plain keeps every landform."""
    from warp_terrain.sim.randomize import randomize

    sim = preset_sim("wide")
    sim.data.randomize.enabled = True
    sim.data.randomize.noise_max = 0.1
    mixed = preset_sim("wide")
    mixed.data.randomize.enabled = True
    mixed.data.randomize.noise_max = 0.1
    mixed.data.randomize.plain_probability = 0.5
    plain_batches = 0
    for seed in range(64):
        (a, amp_a, feat_a), (b, amp_b, feat_b) = randomize(sim, 4, seed), randomize(mixed, 4, seed)
        assert np.array_equal(amp_a, amp_b) and np.array_equal(feat_a, feat_b)
        assert a.lidar == b.lidar and a.data.noise == b.data.noise and a.terrain.octaves == b.terrain.octaves
        assert all(getattr(a.terrain, k) == getattr(b.terrain, k) for k in OBSTACLE_KINDS)
        if b.terrain.tilt.enabled:
            assert b.terrain.tilt == a.terrain.tilt and b.terrain.relief == a.terrain.relief and b.terrain.landforms == a.terrain.landforms
        else:
            plain_batches += 1
            assert not b.terrain.relief.enabled and not b.terrain.landforms.enabled()
    assert 20 <= plain_batches <= 44  # about half of 64 (binomial: 99.9 % within these bounds)
    mixed.data.randomize.plain_probability = 1.0
    assert all(not randomize(mixed, 2, seed)[0].terrain.tilt.enabled for seed in range(8))
    heights = wt.generate_batch(2, mixed, seed=3, device="cpu").heights
    bare = preset_sim("wide")
    bare.terrain.tilt.enabled = bare.terrain.relief.enabled = False
    bare.terrain.landforms = LandformConfig()
    bare.data.randomize.enabled = True
    bare.data.randomize.noise_max = 0.1  # no mix: the landforms are off in the preset itself
    assert torch.equal(heights, wt.generate_batch(2, bare, seed=3, device="cpu").heights)
