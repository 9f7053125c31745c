"""fBm heightfields and obstacles: units, bounds, determinism, and bad input."""

import numpy as np
import pytest
import torch
import warp as wp

import warp_terrain as wt
from warp_terrain.kernels import noise as noise_kernels
from warp_terrain.sim.terrain import ObstacleConfig, TerrainConfig, grid_size, make_heightfields


@wp.kernel
def _noise_at(field: wp.uint32, points: wp.array(dtype=wp.vec2), out: wp.array(dtype=float)):
    k = wp.tid()
    out[k] = wp.noise(field, points[k])


def test_shape_dtype_and_the_height_scale_of_warps_noise():
    """(batch, size, size) float32 on the CPU, and at every vertex the documented sum
    amplitude * sqrt(2) * sum_o p^o noise_o(2^o (x, y) / feature_size + offset_o) / sum_o p^o,
    evaluated here with ``wp.noise`` itself at the vertex's point (the default feature size 8 m:
    every octave of this grid comes from the CPU path's gradient table). Measured 1.3e-7 m off
    on heights up to 0.99 m: tolerance 1e-5 m (a field 29 % flatter is up to 0.29 m off)."""
    batch, size, cell, octaves, amplitude, seed, feature = 3, 49, 0.25, 5, 2.0, 7, 8.0
    h = wt.fractal_heightfield(batch, size, cell, octaves=octaves, amplitude=amplitude, seed=seed, device="cpu")
    assert h.shape == (batch, size, size) and h.dtype == torch.float32 and h.device.type == "cpu"
    fields = wp.empty((batch, octaves), dtype=wp.uint32, device="cpu")
    offsets = wp.empty((batch, octaves), dtype=wp.vec2, device="cpu")
    wp.launch(noise_kernels.octave_fields, dim=fields.shape, inputs=[wp.full(1, seed, dtype=int, device="cpu"), 0], outputs=[fields, offsets], device="cpu")
    u = (np.arange(size) - 0.5 * (size - 1)) * cell / feature
    uv = np.stack(np.meshgrid(u, u, indexing="ij"), axis=-1).reshape(-1, 2)
    out = wp.empty(len(uv), dtype=float, device="cpu")
    for b in range(batch):
        total = np.zeros(len(uv))
        for o in range(octaves):
            points = wp.array((uv * 2.0**o + offsets.numpy()[b, o]).astype(np.float32), dtype=wp.vec2, device="cpu")
            wp.launch(_noise_at, dim=len(uv), inputs=[wp.uint32(int(fields.numpy()[b, o])), points], outputs=[out], device="cpu")
            total += 0.5**o * out.numpy()
        expected = amplitude * np.sqrt(2.0) * total / sum(0.5**o for o in range(octaves))
        np.testing.assert_allclose(h[b].numpy().ravel(), expected, rtol=0, atol=1e-5)
    assert 0.9 < h.abs().max() <= amplitude  # not a flat field: measured 0.99 m


def _per_vertex_wp_noise(batch, size, cfg, seed, feature_size):
    """The reference: one thread per vertex summing ``wp.noise`` octaves (the GPU's default
    path; the ``fbm_table`` kernel switch off)."""
    from warp_terrain.sim.switches import use_kernel_switches

    with use_kernel_switches(fbm_table=False):
        return make_heightfields(batch, size, cfg, seed, "cpu", feature_size=feature_size).numpy()


@pytest.mark.parametrize(
    "terrain, feature_size",
    [
        (dict(octaves=5, feature_size=16.0, amplitude=1.5, cell=0.25), 16.0),  # every octave from the table
        (dict(octaves=5, feature_size=8.0, amplitude=1.5, cell=0.25), 8.0),  # the bench: the finest octave 2 vertices/cell
        (dict(octaves=8, cell=0.125), [3.0, 10.0, 40.0]),  # fine octaves fall back to wp.noise; per-sample features
        (dict(octaves=3, cell=0.5, lacunarity=2.7, persistence=0.6), 40.0),
        (dict(octaves=4, cell=0.25, lacunarity=0.5), 1.0),  # lacunarity < 1: the first octave is the finest
    ],
)
def test_cpu_row_path_equals_wp_noise_per_vertex(terrain, feature_size):
    cfg = TerrainConfig(**terrain)
    batch = 3
    fast = make_heightfields(batch, 97, cfg, 5, "cpu", feature_size=feature_size).numpy()
    reference = _per_vertex_wp_noise(batch, 97, cfg, 5, feature_size)
    np.testing.assert_allclose(fast, reference, rtol=0, atol=1e-6 * cfg.amplitude)


def test_cpu_row_path_reads_only_the_table_entries_it_writes(monkeypatch):
    """The gradient table is sized for the finest octave and coarser octaves fill only their
    own span: with every fresh Warp array poisoned with NaN, the heights are still the
    reference's (a read past an octave's span would be NaN)."""
    empty = wp.empty

    def poisoned(shape, dtype=float, device=None, **kwargs):
        out = empty(shape, dtype=dtype, device=device, **kwargs)
        if dtype is wp.vec2:
            out.fill_(wp.vec2(np.nan, np.nan))
        elif dtype in (float, wp.float32):
            out.fill_(np.nan)
        return out

    monkeypatch.setattr(wp, "empty", poisoned)
    cfg = TerrainConfig(octaves=5, feature_size=8.0, amplitude=1.5, cell=0.25)
    fast = make_heightfields(2, 121, cfg, 9, "cpu").numpy()
    monkeypatch.setattr(wp, "empty", empty)
    np.testing.assert_allclose(fast, _per_vertex_wp_noise(2, 121, cfg, 9, 8.0), rtol=0, atol=1e-6 * cfg.amplitude)


def test_feature_size_is_in_metres():
    # the field depends on x / feature_size only: halving the cell and the wavelength together
    # samples the same points of the same field
    a = wt.fractal_heightfield(2, 33, 0.25, feature_size=4.0, seed=3)
    b = wt.fractal_heightfield(2, 33, 0.5, feature_size=8.0, seed=3)
    torch.testing.assert_close(a, b, rtol=0, atol=1e-6)
    # and a grid twice as fine holds the coarse grid's vertices at every second index
    fine = wt.fractal_heightfield(1, 65, 0.125, feature_size=4.0, seed=3)
    torch.testing.assert_close(fine[:, ::2, ::2], a[:1], rtol=0, atol=1e-6)


def test_amplitude_scales_linearly():
    a = wt.fractal_heightfield(1, 33, 0.25, amplitude=1.0, seed=5)
    b = wt.fractal_heightfield(1, 33, 0.25, amplitude=3.0, seed=5)
    torch.testing.assert_close(3.0 * a, b, rtol=1e-6, atol=1e-6)


def test_more_octaves_add_fine_detail():
    smooth = wt.fractal_heightfield(4, 129, 0.25, octaves=1, seed=2)
    rough = wt.fractal_heightfield(4, 129, 0.25, octaves=6, seed=2)

    def roughness(h):  # mean squared discrete Laplacian: high-frequency energy
        lap = h[:, 1:-1, 1:-1] * 4 - h[:, 2:, 1:-1] - h[:, :-2, 1:-1] - h[:, 1:-1, 2:] - h[:, 1:-1, :-2]
        return float((lap**2).mean() / (h**2).mean())

    assert roughness(rough) > 10 * roughness(smooth)


def test_same_seed_same_terrain_different_seed_different_terrain():
    a = wt.fractal_heightfield(2, 33, 0.25, seed=11)
    b = wt.fractal_heightfield(2, 33, 0.25, seed=11)
    c = wt.fractal_heightfield(2, 33, 0.25, seed=12)
    assert torch.equal(a, b)
    assert (a - c).abs().max() > 0.05
    assert (a[0] - a[1]).abs().max() > 0.05  # samples of one batch differ too


def test_sample_does_not_depend_on_batch_size():
    a = wt.fractal_heightfield(1, 33, 0.25, seed=9)
    b = wt.fractal_heightfield(4, 33, 0.25, seed=9)
    assert torch.equal(a[0], b[0])


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(octaves=0), "octaves"),
        (dict(octaves=-1), "octaves"),
        (dict(cell=0.0), "cell"),
        (dict(cell=-0.1), "cell"),
        (dict(size=1), "size"),
        (dict(batch=0), "batch"),
        (dict(feature_size=0.0), "feature_size"),
        (dict(amplitude=-1.0), "amplitude"),
        (dict(amplitude=float("nan")), "amplitude"),
        (dict(lacunarity=0.0), "lacunarity"),
    ],
)
def test_bad_arguments_name_the_parameter(kwargs, name):
    args = dict(batch=1, size=17, cell=0.25)
    args.update(kwargs)
    with pytest.raises(ValueError, match=name):
        wt.fractal_heightfield(**args)


def _flat_with(kind: str, **sizes) -> np.ndarray:
    cfg = TerrainConfig(amplitude=0.0, octaves=1, cell=0.1, keep_out=1.0)
    setattr(cfg, kind, ObstacleConfig(count_min=1, count_max=1, **sizes))
    cfg.validate()
    return make_heightfields(4, 161, cfg, seed=5, device="cpu", obstacle_region=6.0).numpy()


def test_cylinder_is_a_flat_topped_disc_of_the_drawn_size():
    h = _flat_with("cylinders", width_min=1.2, width_max=1.2, height_min=1.5, height_max=1.5)
    cell = 0.1
    for b in range(h.shape[0]):
        top = h[b] > 0.0
        assert np.allclose(h[b][top], 1.5)  # flat top at its height on flat ground
        radius = np.sqrt(top.sum() * cell**2 / np.pi)
        assert abs(radius - 0.6) < 0.06  # 1.2 m across, to a cell
        ii, jj = np.nonzero(top)
        centre = np.array([ii.mean(), jj.mean()]) - 80
        assert np.linalg.norm(centre) * cell >= 1.0 + 0.6 - cell  # keep_out respected


def test_pit_and_ditch_cut_to_their_depth():
    for kind in ("pits", "ditches"):
        h = _flat_with(kind, width_min=1.0, width_max=1.0, length_min=4.0, length_max=4.0, height_min=0.8, height_max=0.8)
        for b in range(h.shape[0]):
            cut = h[b] < 0.0
            assert cut.sum() > 0
            assert np.allclose(h[b][cut], -0.8)
            area = cut.sum() * 0.01
            expected = np.pi * 0.25 if kind == "pits" else 4.0 * 1.0
            assert abs(area - expected) / expected < 0.15


def _obstacle_counts(cylinders: tuple[int, int], pits: tuple[int, int], batch: int, seed: int) -> np.ndarray:
    """(batch, 2): how many cylinders and pits each flat terrain holds. A cylinder's flat top
    and a pit's floor sit at its own drawn height (0.5-2 m up, 0.2-1 m down), so the distinct
    heights above and below the ground count them; 0.4 m wide in +-7 m, none hides another
    completely at these seeds."""
    cfg = TerrainConfig(amplitude=0.0, octaves=1, cell=0.1, keep_out=0.0)
    size = dict(width_min=0.4, width_max=0.4)
    cfg.cylinders = ObstacleConfig(count_min=cylinders[0], count_max=cylinders[1], height_min=0.5, height_max=2.0, **size)
    cfg.pits = ObstacleConfig(count_min=pits[0], count_max=pits[1], height_min=0.2, height_max=1.0, **size)
    h = make_heightfields(batch, 161, cfg, seed=seed, device="cpu", obstacle_region=7.0).numpy()
    return np.array([(len(np.unique(x[x > 0])), len(np.unique(x[x < 0]))) for x in h])


def test_obstacle_counts_follow_the_config():
    """A fixed count gives exactly that many obstacles of each kind in every sample (none of a
    kind whose count is 0: boxes, rocks, ditches); a range gives every count in it over 64
    samples (measured 17/20/10/17 samples with 1/2/3/4 cylinders) and none outside it."""
    np.testing.assert_array_equal(_obstacle_counts((3, 3), (2, 2), batch=8, seed=1), np.tile([3, 2], (8, 1)))
    counts = _obstacle_counts((1, 4), (0, 2), batch=64, seed=2)
    assert set(counts[:, 0]) == {1, 2, 3, 4}
    assert set(counts[:, 1]) == {0, 1, 2}


def test_bad_obstacle_config_names_the_field():
    cfg = TerrainConfig()
    cfg.pits = ObstacleConfig(count_min=3, count_max=1)
    with pytest.raises(ValueError, match="pits.count_max"):
        cfg.validate()
    cfg = TerrainConfig()
    cfg.boxes = ObstacleConfig(width_min=-1.0)
    with pytest.raises(ValueError, match="boxes.width_min"):
        cfg.validate()


@pytest.mark.parametrize(
    "extent, cell, n",
    [
        (30.25, 0.125, 243),  # the default 121 x 0.25 m map and 1 m margins at 0.125 m
        (10.0, 0.1, 101),
        (1.0, 0.3, 5),
        (1.0, 0.4, 5),  # 1.25 cells each side: rounding would give 3 vertices spanning 0.8 m
        (4.2, 0.3, 15),  # 0.5 * 4.2 / 0.3 = 7.000000000000001 in floats: exactly 7 cells each side
        (0.001, 1.0, 3),
    ],
)
def test_grid_size_is_the_smallest_odd_count_that_covers_the_extent(extent, cell, n):
    assert grid_size(extent, cell) == n
    assert (n - 1) * cell >= extent - 1e-9 > (n - 3) * cell
