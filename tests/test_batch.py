"""generate_batch: shapes, zero-copy hand-off, exact maps on planes, determinism, augmentation, noise."""

import numpy as np
import pytest
import torch

import warp_terrain as wt
from warp_terrain.sim import DataConfig, SimConfig, TerrainConfig
from warp_terrain.sim.batch import terrain_size

MOUNT = 1.8


def small(**data) -> SimConfig:
    """A small, quick setting: 41 x 41 maps of 0.25 m, VLP-16 at 1 degree."""
    d = dict(map_size=41, map_cell=0.25, augment=False)
    d.update(data)
    return SimConfig(
        terrain=TerrainConfig(octaves=3, amplitude=1.0, feature_size=8.0, cell=0.125, margin=2.0),
        lidar=wt.lidar_preset("vlp16", azimuth_step_deg=1.0, range_noise_std=0.0),
        data=DataConfig(**d),
    )


def test_shapes_dtypes_and_device():
    b = wt.generate_batch(3, small(), seed=0, device="cpu")
    for name in ("scan", "mask", "target", "scan_max"):
        t = getattr(b, name)
        assert t.shape == (3, 1, 41, 41) and t.dtype == torch.float32 and t.device.type == "cpu", name
    assert b.points.shape == (3, 16 * 360, 3)
    assert set(b.mask.unique().tolist()) <= {0.0, 1.0}
    assert 0.02 < b.mask.mean() < 0.9


def test_tensors_share_memory_with_the_warp_arrays():
    b = wt.generate_batch(2, small(), seed=0, device="cpu")
    for name in ("scan", "mask", "target", "points"):
        arr = b.warp_arrays[name]
        tensor = getattr(b, name)
        assert tensor.data_ptr() == arr.ptr, name
    # a write through Warp shows up in torch: they are the same memory
    b.warp_arrays["target"].fill_(42.0)
    assert torch.all(b.target == 42.0)


def test_default_config_is_the_paper_map():
    b = wt.generate_batch(1, seed=0)
    assert b.scan.shape == (1, 1, 121, 121)


def test_flat_ground_reads_minus_mount_height_everywhere():
    cfg = small()
    cfg.terrain.amplitude = 0.0
    b = wt.generate_batch(2, cfg, seed=1)
    seen = b.mask > 0
    torch.testing.assert_close(b.target, torch.full_like(b.target, -MOUNT), rtol=0, atol=1e-5)
    torch.testing.assert_close(b.scan[seen], torch.full_like(b.scan[seen], -MOUNT), rtol=0, atol=1e-5)
    assert torch.all(b.scan[~seen] == 0.0)


def test_tilted_plane_target_is_exact_and_scan_matches_within_a_cell():
    cfg = small()
    n = terrain_size(cfg)
    x = (np.arange(n) - (n - 1) / 2) * cfg.terrain.cell
    X, Y = np.meshgrid(x, x, indexing="ij")
    gx, gy = 0.08, -0.05  # gentle slopes so no ray skims the plane
    heights = (gx * X + gy * Y + 0.7)[None].astype(np.float32)
    b = wt.generate_batch(1, cfg, seed=0, heights=heights)
    S, c = cfg.data.map_size, cfg.data.map_cell
    m = (np.arange(S) - (S - 1) / 2) * c
    MX, MY = np.meshgrid(m, m, indexing="ij")
    expected = gx * MX + gy * MY - MOUNT  # the plane at each cell centre, sensor frame
    np.testing.assert_allclose(b.target[0, 0].numpy(), expected, atol=1e-4)
    seen = b.mask[0, 0].numpy() > 0
    # a cell's mean point lies within half a cell diagonal of its centre
    bound = np.hypot(gx, gy) * c * np.sqrt(2) / 2 + 1e-4
    assert np.abs(b.scan[0, 0].numpy()[seen] - expected[seen]).max() <= bound


def test_same_seed_same_batch_different_seed_different_batch():
    cfg = small(noise=0.05, augment=True)
    cfg.lidar.range_noise_std = 0.02
    cfg.lidar.dropout = 0.1
    a = wt.generate_batch(2, cfg, seed=5)
    b = wt.generate_batch(2, cfg, seed=5)
    c = wt.generate_batch(2, cfg, seed=6)
    for name in ("scan", "mask", "target", "heights"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name
    assert torch.equal(a.points.nan_to_num(), b.points.nan_to_num())
    assert (a.heights - c.heights).abs().max() > 0.05
    assert (a.target - c.target).abs().max() > 0.05


DIHEDRAL = [lambda t, k=k, f=f: torch.rot90(t.flip(-1) if f else t, k, (-2, -1)) for f in (0, 1) for k in range(4)]


def test_augmentation_is_an_exact_flip_or_rotation_of_the_same_sample():
    plain = wt.generate_batch(6, small(augment=False), seed=3)
    aug = wt.generate_batch(6, small(augment=True), seed=3)
    assert torch.equal(plain.heights, aug.heights)  # same terrains, only the frame turns
    used = set()
    for b in range(6):
        matches = [
            k
            for k, f in enumerate(DIHEDRAL)
            if torch.equal(f(plain.mask[b]), aug.mask[b])
            and torch.allclose(f(plain.scan[b]), aug.scan[b], atol=1e-5)
            and torch.allclose(f(plain.target[b]), aug.target[b], atol=1e-5)
        ]
        assert matches, f"sample {b} is no dihedral transform of its plain version"
        used.add(matches[0])
    assert len(used) > 1


def test_image_noise_is_scaled_to_the_height_range_and_only_on_observed_cells():
    clean = wt.generate_batch(4, small(noise=0.0, map_size=81), seed=8)
    noisy = wt.generate_batch(4, small(noise=0.10, map_size=81), seed=8)
    assert torch.equal(clean.mask, noisy.mask) and torch.equal(clean.target, noisy.target)
    seen = clean.mask > 0
    assert torch.equal(clean.scan[~seen], noisy.scan[~seen])
    span = clean.target.amax(dim=(1, 2, 3)) - clean.target.amin(dim=(1, 2, 3))
    scaled = ((noisy.scan - clean.scan) / (0.10 * span.view(-1, 1, 1, 1)))[seen]
    assert scaled.numel() > 400
    assert abs(scaled.std().item() - 1.0) < 0.1  # N(0, (noise * height range)^2)
    assert abs(scaled.mean().item()) < 0.15


def test_height_range_is_each_samples_exact_span_reduced_without_atomics():
    import numpy as np
    import warp as wp

    from warp_terrain.kernels import projection as projection_kernels

    rng = np.random.default_rng(3)
    image = rng.normal(size=(3, 1, 7, 5)).astype(np.float32)
    image[1, 0, 6, 4] = 9.0  # the extremes in the last row and column,
    image[2, 0, 0, 0] = -9.0  # in the first, and a constant sample
    image[0] = 0.25
    row_lo, row_hi = (wp.empty((3, 7), dtype=float, device="cpu") for _ in range(2))
    wp.launch(projection_kernels.row_extremes, dim=(3, 7), inputs=[wp.array(image, device="cpu")], outputs=[row_lo, row_hi], device="cpu")
    span = wp.empty(3, dtype=float, device="cpu")
    wp.launch(projection_kernels.height_range, dim=3, inputs=[row_lo, row_hi], outputs=[span], device="cpu")
    assert np.array_equal(span.numpy(), np.ptp(image, axis=(1, 2, 3)))


def test_obstacles_appear_in_target_and_cast_shadows():
    cfg = small()
    cfg.terrain.amplitude = 0.0
    cfg.terrain.cylinders.count_min = cfg.terrain.cylinders.count_max = 3
    cfg.terrain.cylinders.height_min = cfg.terrain.cylinders.height_max = 3.0
    b = wt.generate_batch(2, cfg, seed=2)
    assert (b.target > -MOUNT + 0.5).sum() > 0  # obstacles stand up
    # the same scan without obstacles puts more points on the ground: the rest are shadowed
    cfg.terrain.cylinders.count_min = cfg.terrain.cylinders.count_max = 0
    bare = wt.generate_batch(2, cfg, seed=2)

    def ground_points(batch):
        return int(((batch.points[..., 2] + MOUNT).abs() < 1e-4).sum())

    assert ground_points(bare) > ground_points(b) + 20


def test_hydra_style_config_is_accepted_and_validated():
    from omegaconf import OmegaConf

    run = OmegaConf.create({"terrain": {"octaves": 2}, "data": {"map_size": 21, "augment": False}, "train": {"steps": 3}})
    b = wt.generate_batch(1, run, seed=0)
    assert b.scan.shape == (1, 1, 21, 21)
    with pytest.raises(ValueError, match="octaves"):
        wt.generate_batch(1, {"terrain": {"octaves": 0}})
    with pytest.raises(ValueError, match="map_size"):
        wt.generate_batch(1, {"data": {"map_size": -3}})
    with pytest.raises(ValueError, match="noise"):
        wt.generate_batch(1, {"data": {"noise": 5.0}})
    with pytest.raises(ValueError, match="batch"):
        wt.generate_batch(0)
    with pytest.raises(ValueError, match="heights"):
        wt.generate_batch(1, small(), heights=np.zeros((1, 11, 11), np.float32))
