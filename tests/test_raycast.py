"""Ray casting against heightfields: exact ranges, occlusion shadows, pits, and the mesh reference."""

import math

import numpy as np
import pytest
import torch
import warp as wp

import warp_terrain as wt
from warp_terrain.sim.terrain import ObstacleConfig, TerrainConfig, make_heightfields

MOUNT = 1.8


def quiet(name: str, **overrides) -> wt.LidarConfig:
    """A preset with no range noise and no dropout."""
    return wt.lidar_preset(name, range_noise_std=0.0, dropout=0.0, **overrides)


@pytest.mark.parametrize("preset", ["vlp16", "hdl32e", "hdl64e", "os1-64"])
def test_flat_plane_ranges_are_exact(preset):
    lidar = quiet(preset, max_range=200.0)
    cell, size = 0.5, 401  # +-100 m of flat ground
    flat = np.full((1, size, size), 0.37, dtype=np.float32)  # any constant height
    r = wt.cast_scans(flat, cell, lidar, device="cpu")[0].norm(dim=-1).numpy()
    d = lidar.ray_directions().astype(np.float64)
    half = 0.5 * (size - 1) * cell
    down = d[:, 2] < 0
    expected = np.full(len(d), np.inf)
    expected[down] = MOUNT / -d[down, 2]  # = mount_height / sin(-elevation)
    reach = np.where(down, expected, 0.0)
    landing = np.where(down, np.abs(d[:, :2] * reach[:, None]).max(axis=1), np.inf)  # max(|x|, |y|) on the ground
    inside = down & (landing < half - cell)
    outside = ~down | (landing > half + cell)
    assert inside.sum() > 0.3 * len(d)
    assert np.abs(r[inside] - expected[inside]).max() < 1e-4
    assert np.all(np.isnan(r[outside]))  # upward, or landing off the terrain: no return


def test_points_are_in_the_sensor_frame():
    lidar = quiet("vlp16")
    flat = np.full((161, 161), -3.0, dtype=np.float32)
    p = wt.cast_scans(flat, 0.25, lidar)[0]
    hit = ~torch.isnan(p[:, 0])
    torch.testing.assert_close(p[hit, 2], torch.full_like(p[hit, 2], -MOUNT), rtol=0, atol=2e-5)
    d = torch.from_numpy(lidar.ray_directions())[hit]
    torch.testing.assert_close(p[hit] / p[hit].norm(dim=1, keepdim=True), d, rtol=0, atol=1e-5)


def test_range_limits_noise_and_dropout():
    flat = np.zeros((1, 201, 201), dtype=np.float32)
    exact = wt.cast_scans(flat, 0.25, quiet("vlp16"))
    lidar = wt.lidar_preset("vlp16", range_noise_std=0.05, dropout=0.3)
    noisy = wt.cast_scans(flat, 0.25, lidar, seed=1)
    hit = ~torch.isnan(exact[..., 0])
    kept = ~torch.isnan(noisy[..., 0])
    assert not (kept & ~hit).any()
    assert abs(kept.sum().item() / hit.sum().item() - 0.7) < 0.02
    err = (noisy.norm(dim=-1) - exact.norm(dim=-1))[kept]
    assert abs(err.std().item() - 0.05) < 0.005 and abs(err.mean().item()) < 0.005
    assert torch.equal(wt.cast_scans(flat, 0.25, lidar, seed=1).nan_to_num(), noisy.nan_to_num())
    near = wt.cast_scans(flat, 0.25, quiet("vlp16", min_range=8.0, max_range=10.0))
    r = near.norm(dim=-1)[~torch.isnan(near[..., 0])]
    assert r.numel() > 0 and r.min() >= 8.0 and r.max() <= 10.0


def test_cylinder_shadows_exactly_the_ground_behind_it():
    """A 4 m cylinder 6 m ahead: rays whose ground point lies behind it hit its face instead."""
    cell, size = 0.05, 601  # +-15 m
    x = (np.arange(size) - (size - 1) / 2) * cell
    X, Y = np.meshgrid(x, x, indexing="ij")
    cx, cy, radius, top = 6.0, 1.0, 0.8, 4.0
    h = np.where((X - cx) ** 2 + (Y - cy) ** 2 <= radius**2, top, 0.0).astype(np.float32)
    lidar = quiet("vlp16")
    p = wt.cast_scans(h, cell, lidar)[0].numpy()
    d = lidar.ray_directions().astype(np.float64)
    down = d[:, 2] < 0
    ground = d[down] * (MOUNT / -d[down, 2])[:, None]  # where each ray meets the flat ground
    # horizontal distance from the cylinder's axis to each ray's path up to its ground point
    along = np.clip((d[down, 0] * cx + d[down, 1] * cy) / np.hypot(d[down, 0], d[down, 1]), 0, None)
    reach = np.hypot(ground[:, 0], ground[:, 1])
    dirxy = d[down, :2] / np.hypot(d[down, 0], d[down, 1])[:, None]
    closest = dirxy * np.minimum(along, reach)[:, None]
    miss = np.hypot(closest[:, 0] - cx, closest[:, 1] - cy)
    inside = np.abs(ground).max(axis=1) < 15.0 - 2 * cell
    blocked = (miss < radius - 2 * cell) & inside
    clear = (miss > radius + 2 * cell) & inside
    assert blocked.sum() > 50 and clear.sum() > 1000
    hits = p[down]
    # clear rays reach the ground exactly
    np.testing.assert_allclose(hits[clear], ground[clear], atol=1e-4)
    # blocked rays stop on the cylinder: at its radius from the axis, not on the ground
    on_face = np.hypot(hits[blocked, 0] - cx, hits[blocked, 1] - cy)
    assert np.all(np.abs(on_face - radius) < 2 * cell)
    assert np.all(hits[blocked, 2] > -MOUNT + 1e-3)
    # and no ray lands on the ground inside the shadow
    flat_hits = hits[np.abs(hits[:, 2] + MOUNT) < 1e-4]
    rel = flat_hits[:, :2]
    ang = np.arctan2(rel[:, 1], rel[:, 0]) - math.atan2(cy, cx)
    half_width = math.asin(radius / math.hypot(cx, cy))
    behind = (np.abs(ang) < half_width - 0.02) & (np.hypot(rel[:, 0], rel[:, 1]) > math.hypot(cx, cy))
    assert not behind.any()


def test_pit_floor_is_seen_only_where_geometry_allows():
    """A 1.5 m deep, 9 m long pit starting 8 m ahead: the floor is hidden up to
    d0 * (1 + depth / mount) and the far wall is seen."""
    cell, size = 0.05, 801
    x = (np.arange(size) - (size - 1) / 2) * cell
    X, Y = np.meshgrid(x, x, indexing="ij")
    d0, length, depth = 8.0, 9.0, 1.5
    pit = (X >= d0) & (X <= d0 + length) & (np.abs(Y) <= 3.0)
    h = np.where(pit, -depth, 0.0).astype(np.float32)
    lidar = quiet("hdl64e")
    p = wt.cast_scans(h, cell, lidar)[0].numpy()
    p = p[~np.isnan(p[:, 0])]
    z = p[:, 2] + MOUNT  # height above the ground plane
    in_pit = (p[:, 0] > d0 - cell) & (p[:, 0] < d0 + length + cell) & (np.abs(p[:, 1]) < 2.5)
    floor = in_pit & (z < -depth + 1e-3)
    wall = in_pit & (z < -1e-3) & (z > -depth + 1e-3)
    hidden_until = d0 * (1 + depth / MOUNT) - cell  # the near edge is one cell wide
    assert floor.sum() > 0 and wall.sum() > 0
    assert p[floor, 0].min() >= hidden_until
    assert p[wall, 0].min() > d0 + length - cell  # the wall seen is the far wall
    # the near half of the pit floor gets no points at all
    assert not (in_pit & (p[:, 0] < hidden_until) & (z < -0.05)).any()


@wp.kernel
def _mesh_rays(
    mesh: wp.uint64,
    origin: wp.vec3,
    directions: wp.array(dtype=wp.vec3),
    max_range: float,
    out: wp.array(dtype=float),
):
    r = wp.tid()
    q = wp.mesh_query_ray(mesh, origin, directions[r], max_range)
    out[r] = wp.where(q.result, q.t, -1.0)


def _heightfield_mesh(h: np.ndarray, cell: float) -> wp.Mesh:
    H, W = h.shape
    i, j = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    verts = np.stack([(i - (H - 1) / 2) * cell, (j - (W - 1) / 2) * cell, h], -1).reshape(-1, 3)
    v = lambda a, b: (a * W + b).ravel()  # noqa: E731
    a, b = np.meshgrid(np.arange(H - 1), np.arange(W - 1), indexing="ij")
    # the same diagonal as the heightfield: (i,j)-(i+1,j)-(i+1,j+1) and (i,j)-(i+1,j+1)-(i,j+1)
    tris = np.concatenate(
        [np.stack([v(a, b), v(a + 1, b), v(a + 1, b + 1)], 1), np.stack([v(a, b), v(a + 1, b + 1), v(a, b + 1)], 1)]
    )
    return wp.Mesh(
        points=wp.array(verts.astype(np.float32), dtype=wp.vec3), indices=wp.array(tris.astype(np.int32).ravel(), dtype=int)
    )


def test_traversal_matches_the_triangle_mesh_to_a_millimetre():
    """Random fBm terrains with boxes, rocks, pits and ditches: same hits as wp.mesh_query_ray."""
    cfg = TerrainConfig(octaves=5, amplitude=1.5, feature_size=10.0, cell=0.1, keep_out=2.0)
    cfg.boxes = ObstacleConfig(count_min=2, count_max=4)
    cfg.rocks = ObstacleConfig(count_min=2, count_max=4)
    cfg.pits = ObstacleConfig(count_min=1, count_max=3)
    cfg.ditches = ObstacleConfig(count_min=1, count_max=2)
    cfg.validate()
    lidar = quiet("hdl32e", azimuth_step_deg=1.0)
    heights = make_heightfields(2, 241, cfg, seed=4, device="cpu", obstacle_region=10.0)
    pts = wt.cast_scans(wp.to_torch(heights), cfg.cell, lidar)
    h = heights.numpy()
    dirs = wp.array(lidar.ray_directions(), dtype=wp.vec3)
    for b in range(h.shape[0]):
        mesh = _heightfield_mesh(h[b], cfg.cell)
        centre = (h.shape[1] - 1) // 2
        origin = wp.vec3(0.0, 0.0, float(h[b, centre, centre]) + MOUNT)
        t = wp.zeros(dirs.shape[0], dtype=float)
        wp.launch(_mesh_rays, dim=dirs.shape[0], inputs=[mesh.id, origin, dirs, lidar.max_range], outputs=[t])
        t_mesh = t.numpy()
        r = pts[b].norm(dim=-1).numpy()
        # a ray leaving the terrain's footprint has no return here; the mesh agrees (it ends there too)
        both = (t_mesh > 0) & ~np.isnan(r)
        assert both.sum() > 0.3 * r.size
        np.testing.assert_allclose(r[both], t_mesh[both], atol=1e-3)
        assert np.array_equal(t_mesh > 0, ~np.isnan(r))


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda: wt.cast_scans(np.zeros((9, 9)), 0.0, quiet("vlp16")), "cell"),
        (lambda: wt.cast_scans(np.zeros((9, 9)), -1.0, quiet("vlp16")), "cell"),
        (lambda: wt.cast_scans(np.zeros((2, 3, 9, 9)), 0.1, quiet("vlp16")), "heights"),
        (lambda: wt.cast_scans(np.full((9, 9), np.nan), 0.1, quiet("vlp16")), "heights"),
        (lambda: wt.cast_scans(np.zeros((9, 9)), 0.1, "vlp16"), "lidar"),
        (lambda: wt.cast_scans(np.zeros((9, 9)), 0.1, wt.LidarConfig(elevations_deg=[])), "elevations_deg"),
        (lambda: wt.lidar_preset("vlp17"), "vlp17"),
    ],
)
def test_bad_input_names_the_parameter(call, name):
    with pytest.raises(ValueError, match=name):
        call()


@pytest.mark.parametrize("preset", ["vlp16", "hdl64e", "os1-128"])
def test_column_walk_equals_one_walk_per_ray(preset, monkeypatch):
    """``cast_columns`` (one walk per azimuth column for all rings) returns what ``cast_rays``
    (one walk per ray) returns: same returns, same noise and dropout draws, same flips, to 0.1 mm."""
    from warp_terrain.sim import scan

    cfg = TerrainConfig(octaves=5, amplitude=2.0, feature_size=8.0, cell=0.1, keep_out=1.5)
    cfg.cylinders = ObstacleConfig(count_min=2, count_max=4)
    cfg.boxes = ObstacleConfig(count_min=1, count_max=3)
    cfg.pits = ObstacleConfig(count_min=1, count_max=3)
    cfg.ditches = ObstacleConfig(count_min=1, count_max=2)
    heights = make_heightfields(3, 201, cfg, seed=11, device="cpu", obstacle_region=8.0)
    lidar = wt.lidar_preset(preset, azimuth_step_deg=1.5, dropout=0.1, range_noise_std=0.02)
    results = {}
    for by_column in (False, True):
        monkeypatch.setattr(scan, "columns_walkable", lambda _lidar, flag=by_column: flag)
        for reach in (0.0, 6.0):
            points, _ = scan.trace(heights, cfg.cell, lidar, seed=5, device="cpu", augment=True, reach=reach)
            results[by_column, reach] = points.numpy()
    for reach in (0.0, 6.0):
        per_ray, by_column = results[False, reach], results[True, reach]
        assert np.array_equal(np.isnan(per_ray), np.isnan(by_column))
        assert np.isfinite(per_ray[..., 0]).sum() > 500  # plenty of returns to compare
        np.testing.assert_allclose(by_column, per_ray, atol=1e-4, equal_nan=True)


def test_a_vertical_ring_is_cast_one_ray_at_a_time():
    from warp_terrain.sim.scan import columns_walkable

    lidar = wt.LidarConfig(elevations_deg=[-90.0, -30.0], azimuth_step_deg=10.0, range_noise_std=0.0, mount_height=MOUNT)
    assert not columns_walkable(lidar) and columns_walkable(quiet("hdl32e"))
    pts = wt.cast_scans(np.zeros((81, 81)), 0.1, lidar)[0].numpy()
    ranges = np.linalg.norm(pts, axis=-1).reshape(2, -1)
    np.testing.assert_allclose(ranges[0], MOUNT, atol=1e-4)  # straight down
    np.testing.assert_allclose(ranges[1], MOUNT / math.sin(math.radians(30.0)), atol=1e-4)
