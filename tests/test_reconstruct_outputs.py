"""What ``warp-terrain reconstruct`` writes: .npz or GeoTIFF by the suffix (values and
geotransform read back with rasterio), one file set per input without silent overwrites, a USD
stage of the points and the map, and a PNG of height, mask and uncertainty."""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np
import pytest

from warp_terrain.cli import main
from warp_terrain.core.geometry import MapGeometry
from warp_terrain.inference.maps import map_geotransform, north_up, write_map
from warp_terrain.inference.pointclouds import transform_matrix

rasterio = pytest.importorskip("rasterio")

E, N, Z = 512_345.25, 4_123_456.75, 312.5  # a sensor in UTM coordinates


def _result(S: int, sigma: bool = True) -> dict:
    rng = np.random.default_rng(S)
    result = {"height": rng.normal(size=(S, S)).astype(np.float32), "mask": (rng.random((S, S)) < 0.4).astype(np.float32)}
    if sigma:
        result["uncertainty"] = rng.random((S, S)).astype(np.float32) + 0.01
    return result


def _cell_centres(g: MapGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Sensor-frame x, y of every map cell [p, q] (the design's map frame)."""
    c = g.centres()
    return np.meshgrid(c, c, indexing="ij")


def _raster_centres(ds) -> tuple[np.ndarray, np.ndarray]:
    """World x, y of every raster pixel's centre [row, col], as rasterio computes them."""
    cols, rows = np.meshgrid(np.arange(ds.width), np.arange(ds.height))
    x, y = ds.transform @ (cols + 0.5, rows + 0.5)  # rasterio: transform * (col + 0.5, row + 0.5)
    return np.asarray(x), np.asarray(y)


# ------------------------------------------------------------------------------ write_map: GeoTIFF
def test_geotiff_in_the_sensor_frame_is_north_up_local_metres(tmp_path):
    g = MapGeometry(5, 0.5)
    result = _result(5)
    out = write_map(tmp_path / "map.tif", result, g)
    assert [p.name for p in tmp_path.iterdir()] == ["map.tif"]  # no temporary or sidecar file
    with rasterio.open(out) as ds:
        assert ds.crs is None and ds.count == 3 and ds.dtypes == ("float32",) * 3
        assert tuple(ds.transform)[:6] == (0.5, 0.0, -1.25, 0.0, -0.5, 1.25)  # north up, row 0 at y = +1.25
        assert ds.descriptions == ("height (m)", "mask (1 = observed, 0 = not)", "uncertainty sigma (m)")
        assert ds.units == ("m", None, "m") and np.isnan(ds.nodata)
        bands = ds.read()
        x, y = _raster_centres(ds)
    for band, key in enumerate(("height", "mask", "uncertainty")):
        np.testing.assert_array_equal(bands[band], north_up(result[key]))
    # map cell (p, q) is raster row S-1-q, column p, and its centre is the map's cell centre
    assert bands[0][4 - 1, 3] == result["height"][3, 1]
    X, Y = _cell_centres(g)
    np.testing.assert_array_equal(x, north_up(X))
    np.testing.assert_array_equal(y, north_up(Y))
    assert (x[4 - 1, 3], y[4 - 1, 3]) == (0.5, -0.5)  # cell (3, 1)


@pytest.mark.parametrize("yaw", [0.0, 30.0])
def test_geotiff_with_a_sensor_pose_lies_where_the_cloud_was_in_its_crs(tmp_path, yaw):
    """points -> sensor = translate by -(E, N, Z), then turn by yaw: every cell centre of the
    GeoTIFF is the map's cell centre taken back through the inverse, in float64 (UTM millimetres)."""
    g = MapGeometry(7, 0.25)
    result = _result(7, sigma=False)
    rot = transform_matrix([0, 0, 0, 0, 0, yaw])
    m = rot @ transform_matrix([-E, -N, -Z, 0, 0, 0])
    out = write_map(tmp_path / "map.tiff", result, g, transform=m, crs="EPSG:32633")
    with rasterio.open(out) as ds:
        assert ds.crs == rasterio.crs.CRS.from_epsg(32633)
        bands = ds.read()
        x, y = _raster_centres(ds)
        assert float(ds.tags()["sensor_z"]) == Z
    np.testing.assert_array_equal(bands[0], north_up((result["height"].astype(np.float64) + Z).astype(np.float32)))
    np.testing.assert_array_equal(bands[1], north_up(result["mask"]))
    assert np.isnan(bands[2]).all()  # no uncertainty: nodata
    X, Y = _cell_centres(g)
    world = np.linalg.inv(m) @ np.stack([X.ravel(), Y.ravel(), np.zeros(X.size), np.ones(X.size)])
    np.testing.assert_allclose(x, north_up(world[0].reshape(7, 7)), rtol=0, atol=1e-6)
    np.testing.assert_allclose(y, north_up(world[1].reshape(7, 7)), rtol=0, atol=1e-6)
    if yaw == 0.0:  # north up; the sensor's cell (the middle one) at (E, N)
        assert tuple(ds.transform)[:6] == (0.25, 0.0, E - 0.875, 0.0, -0.25, N + 0.875)
        assert (x[3, 3], y[3, 3]) == (E, N)


def test_geotransform_alone_matches_what_is_written(tmp_path):
    g = MapGeometry(4, 2.0)
    m = transform_matrix([-10.0, 20.0, -1.5, 0, 0, -90.0])
    affine, dz = map_geotransform(g, m)
    write_map(tmp_path / "m.tif", _result(4), g, transform=m)
    with rasterio.open(tmp_path / "m.tif") as ds:
        assert tuple(ds.transform)[:6] == pytest.approx(affine, abs=1e-12)
    assert dz == pytest.approx(1.5)


@pytest.mark.parametrize(
    "name, kwargs, match",
    [
        ("m.tif", dict(transform=transform_matrix([0, 0, 0, 5.0, 0, 0])), "tilts the cloud"),
        ("m.tif", dict(transform=transform_matrix([0, 0, 0, 0, -2.0, 10.0])), "tilts the cloud"),
        ("m.tif", dict(crs="EPSG:999999"), "not a coordinate reference system"),
        ("m.npz", dict(crs="EPSG:32633"), "an .npz map has no coordinate reference system"),
        ("m.png", {}, r"must end in \.npz, \.tif, \.tiff"),
    ],
)
def test_write_map_refuses_before_writing(tmp_path, name, kwargs, match):
    with pytest.raises(ValueError, match=match):
        write_map(tmp_path / name, _result(5), MapGeometry(5, 0.5), **kwargs)
    assert list(tmp_path.iterdir()) == []


def test_geotiff_without_rasterio_says_how_to_install_it(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "rasterio", None)
    with pytest.raises(ValueError, match=r"writing a GeoTIFF needs rasterio: pip install 'warp-terrain\[dem\]'"):
        write_map(tmp_path / "m.tif", _result(5), MapGeometry(5, 0.5))
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------ the PNG
@pytest.mark.parametrize("sigma", [True, False])
def test_preview_shows_height_mask_and_uncertainty_with_colour_bars(tmp_path, sigma):
    from warp_terrain.plots.maps import map_preview_figure, save_map_preview

    r = _result(9, sigma=sigma)
    fig = map_preview_figure(r["height"], r["mask"], 0.5, uncertainty=r.get("uncertainty"), title="scan.ply")
    panels = [ax for ax in fig.axes if ax.get_xlabel() == "x (m)"]
    bars = [ax for ax in fig.axes if ax not in panels]
    assert len(panels) == 3 and [ax.get_ylabel() for ax in panels] == ["y (m)"] * 3
    assert panels[0].get_title() == "reconstructed height (sensor frame)"
    assert panels[1].get_title().startswith("observed cells (")
    labels = [ax.get_ylabel() for ax in bars]
    if sigma:
        assert labels == ["z (m)", "mask (1 = observed, 0 = not)", "sigma (m)"]
        np.testing.assert_array_equal(panels[2].images[0].get_array(), r["uncertainty"].T)
    else:
        assert labels == ["z (m)", "mask (1 = observed, 0 = not)"]
        assert len(panels[2].images) == 0 and "the model predicts none" in panels[2].texts[0].get_text()
    out = save_map_preview(r["height"], r["mask"], 0.5, tmp_path / "p.png", uncertainty=r.get("uncertainty"))
    from PIL import Image

    with Image.open(out) as img:
        assert img.size == (15 * 80, round(4.6 * 80))


# ------------------------------------------------------------------------------ the USD stage
def test_export_reconstruction_holds_the_map_and_the_points_over_it(tmp_path):
    from pxr import Usd, UsdGeom

    from warp_terrain.export import export_reconstruction

    g = MapGeometry(6, 0.5)  # covers [-1.5, 1.5] in x and y
    r = _result(6)
    points = np.array([[0.0, 0.0, -1.0], [1.4, -1.4, -1.2], [1.6, 0.0, -1.1], [0.0, -9.0, -1.0]])
    out = export_reconstruction(tmp_path / "r.usda", r["height"], g.cell, points, mask=r["mask"] > 0, uncertainty=r["uncertainty"])
    stage = Usd.Stage.Open(str(out))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Reconstruction/Map"))
    verts = np.asarray(mesh.GetPointsAttr().Get())
    assert verts.shape == (36, 3)
    X, Y = _cell_centres(g)
    np.testing.assert_array_equal(verts[:, 2], r["height"].ravel())
    np.testing.assert_allclose(verts[:, 0], X.ravel())
    np.testing.assert_allclose(verts[:, 1], Y.ravel())
    assert verts[4 * 6 + 1, 2] == r["height"][4, 1]
    pv = UsdGeom.PrimvarsAPI(mesh)
    np.testing.assert_array_equal(np.asarray(pv.GetPrimvar("observed").Get()), r["mask"].ravel())
    np.testing.assert_array_equal(np.asarray(pv.GetPrimvar("uncertainty").Get()), r["uncertainty"].ravel())
    lidar = np.asarray(UsdGeom.Points(stage.GetPrimAtPath("/World/Sensor/LidarPoints")).GetPointsAttr().Get())
    np.testing.assert_array_equal(lidar, points[:2].astype(np.float32))  # the two over the map
    with pytest.raises(ValueError, match=r"uncertainty: shape \(5, 5\)"):
        export_reconstruction(tmp_path / "bad.usda", r["height"], g.cell, uncertainty=np.ones((5, 5)))


# ------------------------------------------------------------------------------ the command
def _cloud(offset=(0.0, 0.0, 0.0), seed: int = 0) -> np.ndarray:
    """A gently sloping patch of ground 1.8 m under the sensor, plus ``offset``."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-12.0, 12.0, size=(4000, 2))
    z = -1.8 + 0.05 * xy[:, 0] + 0.02 * rng.normal(size=len(xy))
    return np.column_stack([xy, z]) + np.asarray(offset)


def _json_lines(capsys) -> list[dict]:
    return [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")]


def test_cli_geotiff_matches_the_npz_and_lies_in_the_crs(tmp_path, capsys):
    np.save(tmp_path / "utm.npy", _cloud((E, N, Z)))
    pose = f"{-E},{-N},{-Z},0,0,0"
    base = ["reconstruct", str(tmp_path / "utm.npy"), "--transform", pose, "--no-tta"]
    assert main(base + ["--out", str(tmp_path / "local.npz")]) == 0
    assert main(base + ["--out", str(tmp_path / "map.tif"), "--crs", "EPSG:32633"]) == 0
    lines = _json_lines(capsys)
    assert [(d["format"], d["map"], d["png"], d["crs"]) for d in lines] == [
        ("npz", str(tmp_path / "local.npz"), str(tmp_path / "local.png"), None),
        ("tif", str(tmp_path / "map.tif"), str(tmp_path / "map.png"), "EPSG:32633")]
    with np.load(tmp_path / "local.npz") as f:
        npz = {k: f[k] for k in f.files}
    S = npz["height"].shape[0]
    with rasterio.open(tmp_path / "map.tif") as ds:
        bands = ds.read()
        x, y = _raster_centres(ds)
        assert ds.crs.to_epsg() == 32633 and (ds.width, ds.height) == (S, S)
    np.testing.assert_array_equal(bands[0], north_up((npz["height"].astype(np.float64) + Z).astype(np.float32)))
    np.testing.assert_array_equal(bands[1], north_up(npz["mask"]))
    np.testing.assert_array_equal(bands[2], north_up(npz["uncertainty"]))  # the shipped model predicts sigma
    X, Y = _cell_centres(MapGeometry(S, float(npz["map_cell"])))
    np.testing.assert_allclose(x, north_up(X + E), rtol=0, atol=1e-6)
    np.testing.assert_allclose(y, north_up(Y + N), rtol=0, atol=1e-6)
    p, q = 70, 20  # a known cell: its centre in UTM
    assert (x[S - 1 - q, p], y[S - 1 - q, p]) == pytest.approx((E + (p - 60) * 0.25, N + (q - 60) * 0.25), abs=1e-6)
    assert (tmp_path / "map.png").is_file()


@pytest.mark.parametrize(
    "extra, match",
    [
        (["--out", "{t}/m.npz", "--crs", "EPSG:32633"], "--crs 'EPSG:32633': only a GeoTIFF carries a CRS"),
        (["--out", "{t}/m.tif", "--crs", "EPSG:999999"], "--crs='EPSG:999999': not a coordinate reference system"),
        (["--out", "{t}/m.tif", "--transform", "0,0,0,10,0,0"], "--transform '0,0,0,10,0,0': it tilts the cloud"),
        (["--out", "{t}/m.tif", "--format", "npz"], "--format npz contradicts --out"),
        (["--out", "{t}/m.png"], "must end in .npz, .tif or .tiff, or name a folder"),
        (["--usd", "{t}/s.usd"], "--usd '{t}/s.usd': unsupported suffix '.usd'"),
    ],
)
def test_cli_refuses_contradictions_before_work(tmp_path, capsys, extra, match):
    np.save(tmp_path / "a.npy", _cloud())
    before = set(tmp_path.iterdir())
    assert main(["reconstruct", str(tmp_path / "a.npy"), *[e.format(t=tmp_path) for e in extra]]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and match.format(t=tmp_path) in err, err
    assert set(tmp_path.iterdir()) == before


def test_cli_geotiff_without_rasterio_is_refused_before_work(tmp_path, capsys, monkeypatch):
    np.save(tmp_path / "a.npy", _cloud())
    monkeypatch.setitem(sys.modules, "rasterio", None)
    assert main(["reconstruct", str(tmp_path / "a.npy"), "--format", "tif"]) == 2
    assert "writing a GeoTIFF needs rasterio: pip install 'warp-terrain[dem]'" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npy"]


def test_cli_many_inputs_one_file_set_each_never_overwritten(tmp_path, capsys):
    from test_reconstructor import _write

    src = tmp_path / "in"
    src.mkdir()
    _write("ply", src / "scan.ply", _cloud(seed=1).astype(np.float32))
    _write("pcd", src / "scan.pcd", _cloud(seed=2).astype(np.float32))
    np.save(src / "other.npy", _cloud(seed=3))
    inputs = [str(src / n) for n in ("scan.ply", "scan.pcd", "other.npy")]
    out = tmp_path / "maps"  # does not exist yet: made once every check passed
    assert main(["reconstruct", *inputs, "--out", f"{out}/", "--no-tta", "--usd", f"{tmp_path / 'stages'}/"]) == 0
    lines = _json_lines(capsys)
    assert [d["map"] for d in lines] == [str(out / n) for n in ("scan_ply.npz", "scan_pcd.npz", "other.npz")]
    assert sorted(p.name for p in out.iterdir()) == ["other.npz", "other.png", "scan_pcd.npz", "scan_pcd.png", "scan_ply.npz", "scan_ply.png"]
    assert sorted(p.name for p in (tmp_path / "stages").iterdir()) == ["other.usda", "scan_pcd.usda", "scan_ply.usda"]
    with np.load(out / "scan_ply.npz") as a, np.load(out / "scan_pcd.npz") as b:
        assert not np.array_equal(a["height"], b["height"])  # two clouds, two maps
    stamps = {p: p.stat().st_mtime_ns for p in out.iterdir()}

    # again: refused before any work, naming the first file that exists; nothing touched
    assert main(["reconstruct", *inputs, "--out", str(out), "--no-tta"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: {str(out / 'scan_ply.npz')!r}: exists; pass --overwrite to replace it"
    assert {p: p.stat().st_mtime_ns for p in out.iterdir()} == stamps
    assert main(["reconstruct", *inputs, "--out", str(out), "--no-tta", "--overwrite"]) == 0
    assert all(p.stat().st_mtime_ns != stamps[p] for p in out.iterdir())

    # without --out: beside each input, the same names
    assert main(["reconstruct", *inputs[:2], "--no-tta", "--format", "tif"]) == 0
    assert {"scan_ply.tif", "scan_ply.png", "scan_pcd.tif", "scan_pcd.png"} <= {p.name for p in src.iterdir()}
    # one input: its stem alone
    assert main(["reconstruct", inputs[2], "--no-tta"]) == 0
    assert (src / "other.npz").is_file() and (src / "other.png").is_file()


def test_cli_many_inputs_refusals_leave_nothing(tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir(), b.mkdir()
    for folder in (a, b):
        np.save(folder / "scan.npy", _cloud())
    inputs = [str(a / "scan.npy"), str(b / "scan.npy")]
    cases = [
        (["--out", str(tmp_path / "m.npz")], "--out"),
        (["--out", f"{tmp_path / 'new'}/"], "would write it"),  # same stem and suffix in one folder
        (["--usd", str(tmp_path / "s.usda")], "names one stage but 2 inputs were given"),
        (["--out", f"{tmp_path / 'no' / 'such'}/"], "does not exist"),
    ]
    for extra, match in cases:
        assert main(["reconstruct", *inputs, "--no-tta", *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and match in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "b"]  # no folder made by a refused run
    assert main(["reconstruct", *inputs, "--no-tta"]) == 0  # beside each: no clash
    assert (a / "scan.npz").is_file() and (b / "scan.npz").is_file()


def test_plan_never_writes_over_an_input():
    """A map named like its input (an .npz cloud, default naming) takes the suffixed name; an
    --out naming the input is refused even with --overwrite."""
    from pathlib import Path

    from warp_terrain.cli.model import _plan_outputs

    def args(**kw):
        return argparse.Namespace(**{"out": None, "format": None, "usd": None, "crs": None, "overwrite": True, **kw})

    plans, make = _plan_outputs([Path("/nowhere/scan.npz")], args())
    assert (plans[0]["map"], plans[0]["png"], make) == (Path("/nowhere/scan_npz.npz"), Path("/nowhere/scan_npz.png"), [])
    with pytest.raises(ValueError, match="would overwrite the input"):
        _plan_outputs([Path("/tmp/scan.npz")], args(out="/tmp/scan.npz"))


def test_cli_usd_holds_the_points_and_the_map(tmp_path, capsys):
    from pxr import Usd, UsdGeom

    shift = np.array([10.0, -5.0, 2.0])  # a ground frame: the stage is in the sensor frame
    cloud = _cloud(shift)
    np.save(tmp_path / "c.npy", cloud)
    stage_path = tmp_path / "c.usdc"
    assert main(["reconstruct", str(tmp_path / "c.npy"), "--transform", "-10,5,-2,0,0,0", "--no-tta",
                 "--usd", str(stage_path)]) == 0
    (line,) = _json_lines(capsys)
    assert line["usd"] == str(stage_path) and line["map"] == str(tmp_path / "c.npz")
    with np.load(tmp_path / "c.npz") as f:
        height, cell = f["height"], float(f["map_cell"])
    S = height.shape[0]
    stage = Usd.Stage.Open(str(stage_path))
    verts = np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath("/World/Reconstruction/Map")).GetPointsAttr().Get())
    assert verts.shape == (S * S, 3)
    p, q = 70, 20
    assert tuple(verts[p * S + q]) == ((p - 60) * cell, (q - 60) * cell, height[p, q])
    lidar = np.asarray(UsdGeom.Points(stage.GetPrimAtPath("/World/Sensor/LidarPoints")).GetPointsAttr().Get())
    local = cloud - shift
    inside = (np.abs(local[:, 0]) <= S * cell / 2) & (np.abs(local[:, 1]) <= S * cell / 2)
    assert len(lidar) == inside.sum() and np.abs(lidar - local[inside]).max() < 1e-3  # sensor frame
