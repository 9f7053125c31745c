"""terrain=dem: real elevation rasters as terrain, at true scale, with exact geometry checks.

Every raster is written here (GeoTIFF with rasterio, LAS with laspy), so nothing depends on
downloaded data. Maps are small (41 x 41 cells of 0.25 m, a VLP-16 at 2 degrees).
"""

from __future__ import annotations

import math
import re
import sys
import warnings

import numpy as np
import pytest

rasterio = pytest.importorskip("rasterio")
laspy = pytest.importorskip("laspy")
from affine import Affine  # noqa: E402

import warp_terrain as wt  # noqa: E402
from warp_terrain.compose import compose_run, to_run_config  # noqa: E402
from warp_terrain.sim import DataConfig, SimConfig, TerrainConfig  # noqa: E402
from warp_terrain.sim.batch import terrain_size  # noqa: E402
from warp_terrain.sim.dem import DemConfig, DemFileError, dem_windows, load_dem, smooth_fill  # noqa: E402
from warp_terrain.sim.presets import TERRAIN_PRESETS, terrain_preset_names  # noqa: E402
from warp_terrain.sim.terrain import ObstacleConfig, make_heightfields  # noqa: E402

WEST, NORTH = 500000.0, 4000000.0  # UTM 33N (EPSG:32633), metres
UTM = "EPSG:32633"
MAP, MAP_CELL, CELL, MARGIN = 41, 0.25, 0.125, 1.0
SIZE = 99  # terrain vertices: the 10.25 m map plus 1 m each side at 0.125 m
MOUNT = 1.8


def write_tif(path, z, cell, crs=UTM, nodata=None, transform=True):
    """A one-band float32 GeoTIFF, row 0 = north edge, top-left corner at (WEST, NORTH)."""
    kwargs = dict(driver="GTiff", height=z.shape[0], width=z.shape[1], count=1, dtype="float32")
    if transform:
        kwargs["transform"] = Affine(cell, 0.0, WEST, 0.0, -cell, NORTH)
    if crs is not None:
        kwargs["crs"] = crs
    if nodata is not None:
        kwargs["nodata"] = nodata
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(path, "w", **kwargs) as dst:
            dst.write(np.asarray(z, dtype=np.float32), 1)
    return str(path)


def grid(rows, cols, cell):
    """(east, north) of each cell centre, metres from the top-left corner."""
    r, c = np.mgrid[0:rows, 0:cols].astype(np.float64)
    return (c + 0.5) * cell, -(r + 0.5) * cell


def plane_tif(path, a=0.3, b=-0.2, rows=100, cols=90, cell=0.25, base=1200.0, nodata=None, hole=None):
    east, north = grid(rows, cols, cell)
    z = base + a * east + b * north
    if hole is not None:
        z[hole] = nodata if nodata is not None else np.nan
    return write_tif(path, z, cell, nodata=nodata)


def sim_for(files, obstacles=None, **dem) -> SimConfig:
    terrain = TerrainConfig(name="dem", source="dem", cell=CELL, margin=MARGIN, dem=DemConfig(files=list(files), **dem))
    if obstacles:
        terrain.cylinders = obstacles
    return SimConfig(
        terrain=terrain,
        lidar=wt.lidar_preset("vlp16", azimuth_step_deg=2.0, range_noise_std=0.0),
        data=DataConfig(map_size=MAP, map_cell=MAP_CELL, augment=False),
    )


def plane_fit(heights, cell):
    """Least-squares (dz/dx, dz/dy, z0) of ``(S, S)`` heights on the simulator's vertex grid."""
    s = heights.shape[-1]
    x = (np.arange(s) - 0.5 * (s - 1)) * cell
    X, Y = np.meshgrid(x, x, indexing="ij")
    basis = np.column_stack([X.ravel(), Y.ravel(), np.ones(X.size)])
    coef, *_ = np.linalg.lstsq(basis, np.asarray(heights, dtype=np.float64).ravel(), rcond=None)
    return coef, np.abs(basis @ coef - np.asarray(heights, dtype=np.float64).ravel()).max()


def expected_gradient(a, b, draw):
    """d z/d x and d z/d y of the plane ``a east + b north`` seen through a window's heading/mirror."""
    c, s = math.cos(draw.heading), math.sin(draw.heading)
    sign = -1.0 if draw.mirror else 1.0
    return np.array([a * c + b * s, sign * (-a * s + b * c)])


def test_tilted_plane_gives_planes_of_its_slope_and_hits_on_them(tmp_path):
    a, b = 0.3, -0.2
    sim = sim_for([plane_tif(tmp_path / "plane.tif", a, b)])
    batch = wt.generate_batch(6, sim, seed=3, device="cpu")
    assert terrain_size(sim) == SIZE
    heights = batch.heights.numpy()
    targets = batch.target[:, 0].numpy()
    sensor_z = batch.sensor_z.numpy()
    points = batch.points.numpy()
    slope = math.hypot(a, b)
    gradients = []
    for k in range(6):
        coef, residual = plane_fit(heights[k], CELL)
        assert residual < 1e-4 and abs(math.hypot(*coef[:2]) - slope) < 1e-5, k
        coef_map, residual_map = plane_fit(targets[k], MAP_CELL)
        assert residual_map < 1e-4 and abs(math.hypot(*coef_map[:2]) - slope) < 1e-5, k
        np.testing.assert_allclose(coef_map[:2], coef[:2], atol=1e-5)
        assert abs(heights[k, SIZE // 2, SIZE // 2]) < 1e-6 and abs(sensor_z[k] - MOUNT) < 1e-5  # ground under the sensor at 0
        hits = points[k][np.isfinite(points[k]).all(axis=1)]
        assert len(hits) > 300
        plane = coef[0] * hits[:, 0] + coef[1] * hits[:, 1] + coef[2]
        assert np.abs(hits[:, 2] + sensor_z[k] - plane).max() < 1e-3, k
        gradients.append(coef[:2])
    headings = np.degrees(np.arctan2(*np.array(gradients).T))
    assert np.ptp(headings) > 30  # the windows really are turned


def test_heading_and_mirror_turn_the_plane_as_drawn_and_scale_steepens_it(tmp_path):
    a, b = 0.3, -0.2
    path = plane_tif(tmp_path / "plane.tif", a, b)
    dem = load_dem(path)
    cfg = DemConfig(files=[path])
    draws = []
    windows = dem_windows([dem], 8, SIZE, CELL, 11, cfg, draws=draws)
    assert {d.mirror for d in draws} == {False, True}
    for w, d in zip(windows, draws):
        np.testing.assert_allclose(plane_fit(w, CELL)[0][:2], expected_gradient(a, b, d), atol=1e-5)
    fixed = DemConfig(files=[path], heading=False, mirror=False)
    for w in dem_windows([dem], 3, SIZE, CELL, 11, fixed):  # north-up: x east, y north
        np.testing.assert_allclose(plane_fit(w, CELL)[0][:2], [a, b], atol=1e-5)
    with pytest.warns(UserWarning, match="not true scale"):
        half = dem_windows([dem], 3, 41, CELL, 11, DemConfig(files=[path], scale=0.5))
    for w in half:
        assert abs(math.hypot(*plane_fit(w, CELL)[0][:2]) - 2 * math.hypot(a, b)) < 1e-5
    assert "rescaled x0.5" in DemConfig(scale=0.5).label() and DemConfig().label() == "true scale"
    assert np.abs(dem_windows([dem], 2, 41, CELL, 11, DemConfig(files=[path], detrend=True))).max() < 2.5e-4  # float32 steps at 1200 m


def pit_tif(path, radius=2.0, depth=1.0, cells=190, cell=0.1):
    east, north = grid(cells, cells, cell)
    middle = 0.5 * cells * cell
    z = np.full(east.shape, 250.0)
    z[np.hypot(east - middle, north + middle) <= radius] -= depth
    return write_tif(path, z, cell)


def test_pit_has_its_footprint_where_the_draw_puts_it(tmp_path):
    radius, depth, cell = 2.0, 1.0, 0.1
    path = pit_tif(tmp_path / "pit.tif", radius, depth, cell=cell)
    dem = load_dem(path)
    draws = []
    windows = dem_windows([dem], 6, SIZE, CELL, 5, DemConfig(files=[path]), draws=draws)
    x = (np.arange(SIZE) - 0.5 * (SIZE - 1)) * CELL
    X, Y = np.meshgrid(x, x, indexing="ij")
    centre = 0.5 * (np.array(dem.heights.shape) - 1)
    for w, d in zip(windows, draws):
        inside = w < np.median(w) - 0.5 * depth  # (the sensor may stand in the pit)
        assert abs(inside.sum() * CELL**2 / (math.pi * radius**2) - 1) < 0.03
        east, north = (centre[1] - d.col) * cell, -(centre[0] - d.row) * cell
        c, s = math.cos(d.heading), math.sin(d.heading)
        px, py = c * east + s * north, -s * east + c * north
        py = -py if d.mirror else py
        assert math.hypot(X[inside].mean() - px, Y[inside].mean() - py) < 0.02
        ground = w[np.hypot(X - px, Y - py) > radius + 1.0]  # beyond the cubic's ringing at the rim
        assert np.ptp(ground) < 1e-4 and abs(np.median(w[inside]) - np.median(ground) + depth) < 2e-3
    # and the ground-truth map sees the same footprint (cells of 0.25 m, sensor frame)
    batch = wt.generate_batch(3, sim_for([path]), seed=5, device="cpu")
    for target in batch.target[:, 0].numpy():
        area = (target < np.median(target) - 0.5 * depth).sum() * MAP_CELL**2
        assert abs(area / (math.pi * radius**2) - 1) < 0.08


def test_obstacles_stand_on_the_dem(tmp_path):
    path = plane_tif(tmp_path / "plane.tif")
    cylinders = ObstacleConfig(count_min=2, count_max=2, width_min=1.0, width_max=1.0, height_min=1.0, height_max=1.0)
    bare = sim_for([path]).terrain
    stamped = sim_for([path], obstacles=cylinders).terrain
    plain = make_heightfields(2, SIZE, bare, 7, "cpu", obstacle_region=4.0).numpy()
    with_obstacles = make_heightfields(2, SIZE, stamped, 7, "cpu", obstacle_region=4.0).numpy()
    changed = with_obstacles != plain
    for k in range(2):
        area = changed[k].sum() * CELL**2
        assert 0.5 * 2 * math.pi * 0.25 < area < 1.5 * 2 * math.pi * 0.25, area  # two discs of 0.5 m radius
        assert (with_obstacles[k][changed[k]] > plain[k][changed[k]]).all()


def test_nodata_skip_keeps_only_complete_windows(tmp_path):
    rows, cols = 100, 110
    hole = (slice(None), slice(0, 25))  # the western quarter is nodata (-9999)
    path = plane_tif(tmp_path / "holes.tif", rows=rows, cols=cols, nodata=-9999.0, hole=hole)
    dem = load_dem(path)
    assert np.isnan(dem.heights[hole]).all() and np.isfinite(dem.heights[:, 25:]).all()
    draws = []
    windows = dem_windows([dem], 8, SIZE, CELL, 2, DemConfig(files=[path]), draws=draws)
    assert any(d.draws > 1 for d in draws)  # some windows were redrawn
    for w, d in zip(windows, draws):
        assert d.nodata == 0.0 and plane_fit(w, CELL)[1] < 1e-4  # the plane itself, never the fill
    with pytest.raises(ValueError, match=r"holes\.tif.*no window with at most 0% nodata in 3 draws"):
        dem_windows([dem], 40, SIZE, CELL, 2, DemConfig(files=[path], tries=3))


def test_nodata_fill_keeps_windows_and_fills_holes_smoothly(tmp_path):
    east, _ = grid(100, 100, 0.25)
    z = np.full(east.shape, 7.0)
    z[45:55, 40:60] = np.nan  # a hole every window covers
    path = write_tif(tmp_path / "hole.tif", z, 0.25)
    dem = load_dem(path)
    draws = []
    windows = dem_windows([dem], 4, SIZE, CELL, 1, DemConfig(files=[path], nodata="fill"), draws=draws)
    assert all(0.0 < d.nodata < 0.2 and d.draws == 1 for d in draws)
    assert np.isfinite(windows).all() and np.abs(windows).max() < 1e-6  # a constant fills with itself
    with pytest.raises(ValueError, match="no window with at most 0% nodata"):
        dem_windows([dem], 1, SIZE, CELL, 1, DemConfig(files=[path], tries=5))
    draws = []
    dem_windows([dem], 4, SIZE, CELL, 1, DemConfig(files=[path], max_nodata=0.2), draws=draws)
    assert all(0.0 < d.nodata <= 0.2 for d in draws)
    rough = np.random.default_rng(0).normal(size=(40, 50))
    rough[10:20, 5:30] = np.nan
    filled = smooth_fill(rough)
    assert np.isfinite(filled).all() and np.array_equal(filled[np.isfinite(rough)], rough[np.isfinite(rough)].astype(np.float32))


def test_windows_and_batches_come_from_the_seed(tmp_path):
    path = pit_tif(tmp_path / "pit.tif")
    sim = sim_for([path])
    one = wt.generate_batch(3, sim, seed=9, device="cpu")
    two = wt.generate_batch(3, sim, seed=9, device="cpu")
    other = wt.generate_batch(3, sim, seed=10, device="cpu")
    for name in ("heights", "scan", "target", "mask"):
        assert np.array_equal(getattr(one, name).numpy(), getattr(two, name).numpy()), name
    assert not np.array_equal(one.heights.numpy(), other.heights.numpy())
    dem = load_dem(path)
    cfg = DemConfig(files=[path])
    whole = dem_windows([dem], 4, SIZE, CELL, 9, cfg)
    assert np.array_equal(whole[2:], dem_windows([dem], 2, SIZE, CELL, 9, cfg, first=2))  # sample b: (seed, b) only
    assert np.array_equal(one.heights.numpy(), whole[:3])


def test_rasters_load_once_per_process(tmp_path):
    from warp_terrain.sim import dem as dem_module

    path = plane_tif(tmp_path / "plane.tif")
    sim = sim_for([path])
    wt.generate_batch(1, sim, seed=0, device="cpu")
    misses = dem_module._load_cached.cache_info().misses
    wt.generate_batch(2, sim, seed=1, device="cpu")
    assert dem_module._load_cached.cache_info().misses == misses
    assert load_dem(path) is load_dem(str(tmp_path / "." / "plane.tif"))


def las_file(path, cells, cell, ground=True, crs=UTM, holes=()):
    """Four points per cell at +-cell/4 around its centre at the cell's height (class 2 if
    ``ground``), a tree point 8 m above each (class 5), none in the ``holes`` slices."""
    rows, cols = cells.shape
    keep = np.ones(cells.shape, dtype=bool)
    for hole in holes:
        keep[hole] = False
    r, c = np.nonzero(keep)
    east, north = WEST + (c + 0.5) * cell, NORTH - (r + 0.5) * cell
    q = 0.25 * cell
    x = np.concatenate([east + dx for dx in (-q, q, -q, q)] + [east])
    y = np.concatenate([north + dy for dy in (-q, -q, q, q)] + [north])
    z = np.concatenate([cells[r, c]] * 4 + [cells[r, c] + 8.0])
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.offsets = np.array([WEST, NORTH, 0.0])
    header.scales = np.array([0.001, 0.001, 0.001])
    if crs is not None:
        header.vlrs.append(laspy.vlrs.known.WktCoordinateSystemVlr(rasterio.crs.CRS.from_string(crs).to_wkt()))
        header.global_encoding.wkt = True
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z
    cls = np.full(len(x), 5 if ground else 0, dtype=np.uint8)
    cls[: 4 * len(r)] = 2 if ground else 0
    las.classification = cls
    las.write(str(path))
    return str(path)


def test_las_ground_points_round_trip_to_the_raster(tmp_path):
    rng = np.random.default_rng(4)
    cell = 0.5
    cells = np.round(300.0 + np.cumsum(rng.normal(0, 0.05, (30, 40)), axis=1), 3)  # mm, like the LAS
    small, large = (slice(10, 12), slice(10, 12)), (slice(18, 26), slice(20, 30))
    las = load_dem(las_file(tmp_path / "ground.las", cells, cell, holes=(small, large)), ground_cell=cell)
    tif = load_dem(write_tif(tmp_path / "ground.tif", cells, cell))
    assert las.heights.shape == tif.heights.shape == cells.shape and las.cell_m == tif.cell_m == cell
    assert las.origin == pytest.approx(tif.origin, abs=1e-9) and las.crs == tif.crs == UTM
    known = np.ones(cells.shape, dtype=bool)
    known[small] = known[large] = False
    np.testing.assert_allclose(las.heights[known], tif.heights[known], atol=1e-5)  # trees left out
    assert np.isfinite(las.heights[small]).all()  # a small hole is filled
    assert (las.heights[small] > cells.min() - 0.01).all() and (las.heights[small] < cells.max() + 0.01).all()
    assert np.isnan(las.heights[large]).all()  # a large gap stays nodata


def test_unclassified_las_uses_the_csf_ground_filter_or_says_to_install_it(tmp_path, monkeypatch):
    pytest.importorskip("CSF")
    cells = np.full((30, 40), 100.0)
    path = las_file(tmp_path / "raw.las", cells, 0.5, ground=False)
    dem = load_dem(path, ground_cell=0.5)
    assert np.nanmax(np.abs(dem.heights - 100.0)) < 0.05  # the tree points are not ground
    monkeypatch.setitem(sys.modules, "CSF", None)
    with pytest.raises(DemFileError, match=r"raw2\.las: has no ground-classified points.*cloth-simulation-filter"):
        load_dem(las_file(tmp_path / "raw2.las", cells, 0.5, ground=False), ground_cell=0.5)


def test_npz_fixture_loads_in_metres(tmp_path):
    heights = np.arange(12.0).reshape(3, 4)
    np.savez(tmp_path / "fixture.npz", heights=heights, cell=0.5)
    dem = load_dem(tmp_path / "fixture.npz")
    assert dem.cell_m == 0.5 and np.array_equal(dem.heights, heights.astype(np.float32))


def test_preset_and_hydra_compose(tmp_path):
    assert "dem" in TERRAIN_PRESETS and "dem" not in terrain_preset_names()  # 'all' runs without files
    path = plane_tif(tmp_path / "plane.tif")
    run = compose_run(["terrain=dem", f"terrain.dem.files=[{path}]", "terrain.dem.nodata=fill"])
    assert run.terrain.source == "dem" and run.terrain.dem.files == [path] and run.terrain.dem.nodata == "fill"
    with pytest.raises(ValueError, match=r"^terrain\.dem\.files=\[\]: give at least one raster"):
        compose_run(["terrain=dem"])


def test_randomisation_draws_sensor_and_obstacles_on_dem_ground(tmp_path):
    sim = sim_for([plane_tif(tmp_path / "plane.tif")])
    sim.data.randomize.enabled = True
    sim.data.randomize.lidars = ["vlp16"]
    sim.data.randomize.azimuth_step_min_deg = 2.0
    batch = wt.generate_batch(2, sim, seed=4, device="cpu")
    assert np.isfinite(batch.target.numpy()).all() and batch.mask.numpy().mean() > 0.02


# ------------------------------------------------------------------------------ bad input
def refused(tmp_path, files, **dem):
    with pytest.raises(ValueError) as info:
        to_run_config({"terrain": {"source": "dem", "dem": {"files": [str(f) for f in files], **dem}}})
    message = str(info.value)
    assert "\n" not in message
    return message


def test_bad_files_are_refused_naming_them(tmp_path):
    east, north = grid(100, 100, 0.25)
    z = 10.0 + 0.1 * east
    (tmp_path / "text.tif").write_text("not a raster")
    cases = {
        "text.tif": "not a readable raster",
        "nocrs.tif": "has no CRS.*assume_metres=true",
        "degrees.tif": "not projected",
        "feet.tif": "not metres",
        "nogeo.tif": "no geotransform",
        "empty.tif": "no valid elevation",
        "missing.tif": "no such file",
        "nocrs.las": "has no CRS",
        "text.las": "not a readable LAS",
    }
    write_tif(tmp_path / "nocrs.tif", z, 0.25, crs=None)
    write_tif(tmp_path / "degrees.tif", z, 0.25, crs="EPSG:4326")
    write_tif(tmp_path / "feet.tif", z, 0.25, crs="EPSG:2227")
    write_tif(tmp_path / "nogeo.tif", z, 0.25, crs=None, transform=False)
    write_tif(tmp_path / "empty.tif", np.full(z.shape, -9999.0), 0.25, nodata=-9999.0)
    las_file(tmp_path / "nocrs.las", z[:20, :20], 0.5, crs=None)
    (tmp_path / "text.las").write_text("not a point cloud")
    good = plane_tif(tmp_path / "good.tif")
    for name, why in cases.items():
        path = tmp_path / name
        message = refused(tmp_path, [good, path])
        assert message.startswith(f"terrain.dem.files[1]={str(path)!r}: ") and re.search(why, message), (name, message)
    assert to_run_config({"terrain": {"source": "dem", "dem": {"files": [str(tmp_path / "nocrs.tif")], "assume_metres": True}}})


def test_a_recorded_config_can_be_read_without_its_files(tmp_path):
    from warp_terrain.sim.batch import as_sim_config

    recorded = {"terrain": {"source": "dem", "dem": {"files": [str(tmp_path / "elsewhere.tif")]}}}
    with pytest.raises(ValueError, match=r"dem\.files\[0\]=.*elsewhere\.tif': no such file"):
        as_sim_config(recorded)
    assert as_sim_config(recorded, files=False).terrain.dem.files == [str(tmp_path / "elsewhere.tif")]


def test_too_small_raster_and_empty_list_are_refused_before_any_batch(tmp_path):
    small = plane_tif(tmp_path / "small.tif", rows=60, cols=200)
    big = plane_tif(tmp_path / "big.tif")
    sim = sim_for([big, small])
    with pytest.raises(ValueError, match=r"^terrain\.dem\.files\[1\]='.*small\.tif': 60 x 200 cells of 0\.25 m is too small for a 12\.25 m window"):
        sim.validate()
    with pytest.raises(ValueError, match="too small"):
        wt.generate_batch(1, sim, seed=0, device="cpu")
    sim_for([big, small], heading=False).validate()  # north-up windows need only the side
    with pytest.raises(ValueError, match=r"^dem\.files=\[\]: give at least one raster"):
        sim_for([]).validate()
    with pytest.raises(ValueError, match=r"^terrain\.dem\.files\[0\]='': must be a non-empty path"):
        to_run_config({"terrain": {"dem": {"files": [""]}}})


def test_randomised_fbm_world_mixes_in_real_ground_by_dem_probability(tmp_path):
    """``dem_probability=1``: every batch of the fBm world is cut from the raster (the plane's
    slope shows in the terrain); 0 keeps the fBm; asking for it without files is refused."""
    path = plane_tif(tmp_path / "plane.tif", a=0.3, b=-0.2)
    sim = sim_for([path])
    sim.terrain.source = "fbm"
    sim.data.randomize.enabled = True
    sim.data.randomize.lidars = ["vlp16"]
    sim.data.randomize.azimuth_step_min_deg = 2.0
    sim.data.randomize.obstacle_probability = 0.0
    sim.data.randomize.dem_probability = 1.0
    sim.validate()
    heights = wt.generate_batch(2, sim, seed=5, device="cpu").heights.numpy()
    for h in heights:
        (gx, gy, _), worst = plane_fit(h, CELL)
        assert worst < 1e-3 and math.isclose(math.hypot(gx, gy), math.hypot(0.3, 0.2), rel_tol=1e-3)
    sim.data.randomize.dem_probability = 0.0
    heights = wt.generate_batch(2, sim, seed=5, device="cpu").heights.numpy()
    assert all(plane_fit(h, CELL)[1] > 0.01 for h in heights)  # fBm relief, not a plane
    with pytest.raises(ValueError, match=r"^data\.randomize\.dem_probability=0\.5: .*terrain\.dem\.files"):
        to_run_config({"data": {"randomize": {"enabled": True, "dem_probability": 0.5}}})


def test_a_replayed_batch_refuses_dem_ground(tmp_path):
    from warp_terrain.sim.graph import BatchGraph

    with pytest.raises(ValueError, match="terrain.source='dem': must be fbm: DEM windows are cut on the host for each seed"):
        BatchGraph(2, sim_for([plane_tif(tmp_path / "plane.tif")]), device="cpu")
