"""LidarConfig and the sensor presets: published tables, ray layout, validation, copies."""

import dataclasses
import math

import numpy as np
import pytest

import warp_terrain as wt
from warp_terrain.sim.lidar import LIDAR_PRESETS, LidarConfig, lidar_preset, lidar_preset_names

PRESETS = ["vlp16", "hdl32e", "hdl64e", "os1-64", "os1-128"]


def test_preset_names():
    assert sorted(lidar_preset_names()) == sorted(PRESETS)
    assert sorted(LIDAR_PRESETS) == sorted(PRESETS)


@pytest.mark.parametrize(
    "name, channels, columns",
    [
        ("vlp16", 16, 1800),
        ("hdl32e", 32, 2250),
        ("hdl64e", 64, 2083),
        ("os1-64", 64, 2048),
        ("os1-128", 128, 2048),
    ],
)
def test_published_channel_and_column_counts(name, channels, columns):
    cfg = lidar_preset(name)
    assert cfg.name == name
    assert cfg.channels == channels
    assert cfg.columns == columns
    assert cfg.num_rays == channels * columns
    assert cfg.source  # every preset says where its numbers come from


@pytest.mark.parametrize("name", PRESETS)
def test_elevations_sorted_unique_and_valid(name):
    cfg = lidar_preset(name)
    e = np.asarray(cfg.elevations_deg)
    assert np.all(np.diff(e) > 0), "ascending and unique"
    assert cfg.validate() is cfg
    assert cfg.mount_height == 1.8
    assert cfg.dropout == 0.0
    assert cfg.fov_deg == 360.0


def test_vlp16_table():
    assert lidar_preset("vlp16").elevations_deg == [float(a) for a in range(-15, 16, 2)]


def test_hdl32e_table():
    e = np.asarray(lidar_preset("hdl32e").elevations_deg)
    assert e[0] == -30.67 and e[-1] == 10.67
    assert 0.0 in e
    # 4/3 deg apart, as printed to 0.01 deg in the manual
    np.testing.assert_allclose(np.diff(e), 4.0 / 3.0, atol=0.011)


def test_hdl64e_table_is_the_uneven_two_block_calibration():
    e = np.asarray(lidar_preset("hdl64e").elevations_deg)
    assert e[-1] == pytest.approx(math.degrees(0.03421014630846329))  # +1.960
    assert e[0] == pytest.approx(math.degrees(-0.4285668719175616))  # -24.555
    assert e[-1] == pytest.approx(1.960, abs=1e-3)
    assert e[0] == pytest.approx(-24.555, abs=1e-3)
    lower, upper = e[:32], e[32:]
    assert upper[0] == pytest.approx(-8.5626, abs=1e-3)
    assert lower[-1] == pytest.approx(-8.7745, abs=1e-3)
    # the two blocks have distinct spacing: ~1/3 deg above, ~1/2 deg below
    assert np.diff(upper).mean() == pytest.approx(1.0 / 3.0, abs=0.01)
    assert np.diff(lower).mean() == pytest.approx(0.5, abs=0.01)
    # a real per-laser table, not an even spread within each block
    assert np.diff(upper).std() > 0.01
    assert np.diff(lower).std() > 0.01


@pytest.mark.parametrize(
    "name, lo, hi, step_mean",
    [("os1-64", -21.41, 21.02, 0.67), ("os1-128", -21.62, 21.34, 0.34)],
)
def test_ouster_tables(name, lo, hi, step_mean):
    cfg = lidar_preset(name)
    e = np.asarray(cfg.elevations_deg)
    assert e[0] == lo and e[-1] == hi
    assert np.diff(e).mean() == pytest.approx(step_mean, abs=0.01)
    assert cfg.azimuth_step_deg == 360.0 / 2048


def test_ray_directions_unit_and_layout():
    cfg = lidar_preset("hdl32e")
    d = cfg.ray_directions()
    assert d.shape == (cfg.num_rays, 3)
    assert d.dtype == np.float32
    assert d.flags["C_CONTIGUOUS"]
    np.testing.assert_allclose(np.linalg.norm(d.astype(np.float64), axis=1), 1.0, atol=1e-6)
    for ring, col in [(0, 0), (0, 1), (15, 0), (31, 2249), (7, 1125), (31, 562)]:
        row = d[ring * cfg.columns + col].astype(np.float64)
        elev = math.degrees(math.asin(row[2]))
        azim = math.degrees(math.atan2(row[1], row[0])) % 360.0
        assert elev == pytest.approx(cfg.elevations_deg[ring], abs=1e-4)
        assert azim == pytest.approx((col * cfg.azimuth_step_deg) % 360.0, abs=1e-4)


def test_ray_directions_axes():
    # x forward, y left (azimuth towards +y), z up
    cfg = LidarConfig(elevations_deg=[0.0, 90.0, -30.0], azimuth_step_deg=90.0)
    d = cfg.ray_directions().reshape(cfg.channels, cfg.columns, 3)
    assert cfg.elevations_deg == [-30.0, 0.0, 90.0]  # stored ascending
    np.testing.assert_allclose(d[1, 0], [1, 0, 0], atol=1e-7)
    np.testing.assert_allclose(d[1, 1], [0, 1, 0], atol=1e-7)
    np.testing.assert_allclose(d[1, 2], [-1, 0, 0], atol=1e-7)
    np.testing.assert_allclose(d[1, 3], [0, -1, 0], atol=1e-7)
    np.testing.assert_allclose(d[2, 1], [0, 0, 1], atol=1e-7)
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    np.testing.assert_allclose(d[0, 0], [c, 0, -s], atol=1e-7)


def test_partial_fov_and_start():
    cfg = LidarConfig(elevations_deg=[-5.0, 5.0], azimuth_step_deg=1.0,
                      azimuth_start_deg=-45.0, fov_deg=90.0)
    assert cfg.columns == 90
    az = cfg.azimuths_deg()
    assert az[0] == -45.0 and az[-1] == 44.0
    d = cfg.ray_directions()
    first = d[0].astype(np.float64)
    assert math.degrees(math.atan2(first[1], first[0])) == pytest.approx(-45.0, abs=1e-4)


def test_default_config_is_the_vlp16_and_its_rings_land_where_the_mount_height_puts_them():
    """The defaults are the VLP-16's geometry under the name "custom". Cast over flat ground
    (+-120 m, so only the range window cuts rays), ring e < 0 lands on the circle of horizontal
    radius mount_height / tan(-e) at z = -mount_height, every column; rings at or above the
    horizon see nothing. At the default 1.8 m the -1 deg ring would reach 1.8 / sin(1 deg) =
    103.1 m, beyond max_range 100 m: no return; at 1.7 m it reaches 97.4 m and returns.
    float32 casts: measured 2.2e-7 relative error, tolerance 1e-6."""
    cfg = LidarConfig()
    vlp16 = lidar_preset("vlp16")
    assert (cfg.name, cfg.source) == ("custom", "user-defined")
    for f in dataclasses.fields(LidarConfig):
        if f.name not in ("name", "source"):
            assert getattr(cfg, f.name) == getattr(vlp16, f.name), f.name
    assert cfg.validate() is cfg and (cfg.channels, cfg.columns, cfg.num_rays) == (16, 1800, 28800)

    flat = np.full((121, 121), -0.6, np.float32)  # any constant ground height
    for mount, lowest_missing in [(1.8, -1.0), (1.7, 1.0)]:
        quiet = dataclasses.replace(cfg, range_noise_std=0.0, mount_height=mount)
        points = wt.cast_scans(flat, 2.0, quiet, device="cpu")[0].numpy().astype(np.float64)
        points = points.reshape(cfg.channels, cfg.columns, 3)
        for ring, elevation in enumerate(cfg.elevations_deg):
            hit = ~np.isnan(points[ring, :, 0])
            if elevation >= lowest_missing:
                assert not hit.any(), (mount, elevation)
                continue
            assert hit.all(), (mount, elevation)
            radius = mount / math.tan(math.radians(-elevation))
            np.testing.assert_allclose(np.hypot(points[ring, :, 0], points[ring, :, 1]), radius, rtol=1e-6, atol=0)
            np.testing.assert_allclose(points[ring, :, 2], -mount, rtol=1e-6, atol=0)


def test_lidar_preset_returns_copies():
    a = lidar_preset("vlp16")
    a.elevations_deg.append(20.0)
    a.max_range = 1.0
    a.name = "changed"
    b = lidar_preset("vlp16")
    assert b is not a
    assert b.elevations_deg is not a.elevations_deg
    assert b.channels == 16 and b.max_range == 100.0 and b.name == "vlp16"
    assert LIDAR_PRESETS["vlp16"].channels == 16
    assert b.elevations_deg is not LIDAR_PRESETS["vlp16"].elevations_deg


def test_lidar_preset_name_forms_and_overrides():
    assert lidar_preset("OS1_64").name == "os1-64"
    cfg = lidar_preset("hdl64e", range_noise_std=0.05, dropout=0.1)
    assert cfg.range_noise_std == 0.05 and cfg.dropout == 0.1
    assert LIDAR_PRESETS["hdl64e"].range_noise_std == 0.02
    with pytest.raises(ValueError, match="dropout"):
        lidar_preset("hdl64e", dropout=1.5)
    with pytest.raises(ValueError, match="not_a_field"):
        lidar_preset("hdl64e", not_a_field=1)


def test_unknown_preset():
    with pytest.raises(ValueError) as err:
        lidar_preset("hdl128x")
    msg = str(err.value)
    assert "hdl128x" in msg
    for name in PRESETS:
        assert name in msg


def test_constructor_does_not_alias_the_callers_list():
    angles = [3.0, -1.0, 2.0]
    cfg = LidarConfig(elevations_deg=angles)
    assert cfg.elevations_deg == [-1.0, 2.0, 3.0]
    assert angles == [3.0, -1.0, 2.0]


BAD_VALUES = [
    ("elevations_deg", []),
    ("elevations_deg", [0.0, 91.0]),
    ("elevations_deg", [-90.5]),
    ("elevations_deg", [0.0, float("nan")]),
    ("elevations_deg", [float("inf")]),
    ("elevations_deg", None),
    ("azimuth_step_deg", 0.0),
    ("azimuth_step_deg", -0.2),
    ("azimuth_step_deg", float("nan")),
    ("azimuth_step_deg", 1000.0),  # larger than twice the fov: no columns
    ("azimuth_start_deg", float("inf")),
    ("fov_deg", 0.0),
    ("fov_deg", -10.0),
    ("fov_deg", 360.5),
    ("fov_deg", float("nan")),
    ("min_range", -0.1),
    ("min_range", float("nan")),
    ("max_range", 0.5),  # == min_range of the vlp16 preset
    ("max_range", 0.1),
    ("max_range", float("inf")),
    ("range_noise_std", -0.01),
    ("range_noise_std", float("nan")),
    ("dropout", -0.1),
    ("dropout", 1.0),
    ("dropout", float("nan")),
    ("mount_height", 0.0),
    ("mount_height", -1.8),
    ("mount_height", float("inf")),
    ("mount_height", True),
    ("max_range", "100"),
]


@pytest.mark.parametrize("field_name, value", BAD_VALUES)
def test_invalid_field_names_the_field(field_name, value):
    cfg = dataclasses.replace(lidar_preset("vlp16"), **{field_name: value})
    with pytest.raises(ValueError, match=field_name):
        cfg.validate()
    with pytest.raises(ValueError, match=field_name):
        cfg.ray_directions()


def test_hydra_structured_config_roundtrip():
    omegaconf = pytest.importorskip("omegaconf")
    OmegaConf = omegaconf.OmegaConf
    schema = OmegaConf.structured(LidarConfig)
    merged = OmegaConf.merge(schema, OmegaConf.structured(lidar_preset("os1-128")))
    merged = OmegaConf.merge(merged, OmegaConf.from_dotlist(["dropout=0.2"]))
    cfg = OmegaConf.to_object(merged)
    assert isinstance(cfg, LidarConfig)
    assert cfg.channels == 128 and cfg.dropout == 0.2
    assert cfg.validate().num_rays == 128 * 2048
    with pytest.raises(omegaconf.errors.ValidationError):
        OmegaConf.merge(schema, OmegaConf.from_dotlist(["max_range=far"]))
