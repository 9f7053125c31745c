"""Reconstructor, point-cloud files and ONNX export."""

import warnings

import numpy as np
import pytest
import torch

import warp_terrain as wt
from warp_terrain.inference.onnx import check_onnx, export_onnx
from warp_terrain.inference.pointclouds import apply_transform, read_point_cloud, transform_matrix
from warp_terrain.inference.reconstructor import Reconstructor
from warp_terrain.models import ModelConfig, build_generator
from warp_terrain.models.fill import push_pull_fill

SMALL = ModelConfig(name="unet", in_channels=2, residual=True, ngf=8, ndf=8, unet_depth=4)


def _untrained(tmp_path, tta: bool = True) -> Reconstructor:
    torch.manual_seed(0)
    rec = Reconstructor(build_generator(SMALL), SMALL, {"note": "test"}, device="cpu")
    path = tmp_path / "rec.pt"
    rec.save(path)
    return Reconstructor.load(path, device="cpu", tta=tta)


def _scan(seed=0) -> np.ndarray:
    b = wt.generate_batch(1, seed=seed)
    p = b.points[0].numpy()
    return p[~np.isnan(p[:, 0])]


def test_save_load_round_trip_with_weights_only(tmp_path, monkeypatch):
    loads = []
    real_load = torch.load

    def spy(*args, **kwargs):
        loads.append(kwargs.get("weights_only"))
        return real_load(*args, **kwargs)

    monkeypatch.setattr(torch, "load", spy)
    rec = _untrained(tmp_path)
    assert loads and all(w is True for w in loads)
    assert rec.model_config == SMALL and rec.meta == {"note": "test"}


def test_reconstruct_keeps_the_fill_structure_of_an_untrained_residual_net(tmp_path):
    """The residual model is the push-pull fill plus a correction: zero the net's last layer
    and reconstruct() must return exactly the fill of the projected scan."""
    rec = _untrained(tmp_path, tta=False)
    last = [m for m in rec.generator.modules() if isinstance(m, torch.nn.ConvTranspose2d)][-1]
    torch.nn.init.zeros_(last.weight)
    torch.nn.init.zeros_(last.bias)
    points = _scan()
    height = rec.reconstruct(points)
    assert height.shape == (121, 121) and height.dtype == np.float32
    scan, mask = wt.project_points(points)
    np.testing.assert_allclose(height, push_pull_fill(scan, mask)[0, 0].numpy(), atol=1e-5)


class _ScanPlusRamp(torch.nn.Module):
    """height = scan + (column - centre): the ramp turns with each orientation, so the average
    of the 8 orientations, mapped back, cancels it; log-variance channel: a constant 2 log 0.3."""

    def forward(self, condition):
        scan = condition[:, :1]
        ramp = torch.arange(scan.shape[-1], dtype=scan.dtype) - (scan.shape[-1] - 1) / 2
        return torch.cat([scan + ramp, torch.full_like(scan, 2 * np.log(0.3))], dim=1)


def test_test_time_augmentation_averages_the_eight_orientations():
    cfg = ModelConfig(name="unet", in_channels=2, uncertainty=True)
    scan, mask = torch.randn(2, 1, 121, 121), torch.ones(2, 1, 121, 121)
    plain = Reconstructor(_ScanPlusRamp(), cfg, device="cpu", tta=False).predict_maps_with_uncertainty(scan, mask)
    ramp = torch.arange(121.0) - 60.0
    torch.testing.assert_close(plain[0], scan + ramp)
    height, sigma = Reconstructor(_ScanPlusRamp(), cfg, device="cpu").predict_maps_with_uncertainty(scan, mask)
    torch.testing.assert_close(height, scan, atol=1e-5, rtol=0)
    torch.testing.assert_close(sigma, torch.full_like(scan, 0.3))


@pytest.mark.parametrize(
    "points, message",
    [
        (np.zeros((0, 3), np.float32), "empty"),
        (np.zeros((10, 2), np.float32), "shape"),
        (np.array([["a", "b", "c"]]), "dtype"),
        (np.full((5, 3), np.nan, np.float32), "NaN"),
        (np.full((5, 3), 1000.0, np.float32), "none of the"),
    ],
)
def test_bad_clouds_fail_clearly(tmp_path, points, message):
    rec = _untrained(tmp_path)
    with pytest.raises(ValueError, match=message):
        rec.reconstruct(points)


def test_nan_rows_are_dropped_with_a_warning(tmp_path):
    rec = _untrained(tmp_path)
    points = _scan()
    dirty = np.concatenate([points, np.full((7, 3), np.inf, np.float32)])
    with pytest.warns(UserWarning, match="dropped 7"):
        a = rec.reconstruct(dirty)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        b = rec.reconstruct(points)
    np.testing.assert_array_equal(a, b)


def _write(fmt: str, path, xyz: np.ndarray) -> None:
    if fmt == "npy":
        np.save(path, xyz)
    elif fmt == "ply":
        from plyfile import PlyData, PlyElement

        v = np.array([tuple(p) for p in xyz], dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
        PlyData([PlyElement.describe(v, "vertex")]).write(str(path))
    elif fmt == "pcd":
        from pypcd4 import PointCloud

        PointCloud.from_xyz_points(xyz).save(str(path))
    else:
        import laspy

        header = laspy.LasHeader(point_format=3, version="1.2")
        header.scales = np.array([0.0001, 0.0001, 0.0001])
        header.offsets = xyz.min(axis=0)
        las = laspy.LasData(header)
        las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        las.write(str(path))


@pytest.mark.parametrize("fmt", ["npy", "ply", "pcd", "las", "laz"])
def test_each_file_format_round_trips(tmp_path, fmt):
    xyz = (np.random.default_rng(0).normal(size=(500, 3)) * 5).astype(np.float32)
    path = tmp_path / f"cloud.{fmt}"
    _write(fmt, path, xyz)
    got = read_point_cloud(path)
    np.testing.assert_allclose(got, xyz, atol=1e-4 if fmt in ("las", "laz") else 0)


def test_unreadable_files_name_the_problem(tmp_path):
    with pytest.raises(ValueError, match="no such file"):
        read_point_cloud(tmp_path / "missing.ply")
    with pytest.raises(ValueError, match="unsupported"):
        read_point_cloud(tmp_path / "cloud.obj")
    bad = tmp_path / "broken.ply"
    bad.write_bytes(b"not a ply file")
    with pytest.raises(ValueError, match="broken.ply"):
        read_point_cloud(bad)
    obj = tmp_path / "pickle.npy"
    np.save(obj, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(ValueError, match="pickle.npy"):
        read_point_cloud(obj)  # never unpickles


def test_transforms():
    m = transform_matrix([1.0, 2.0, 3.0, 0.0, 0.0, 90.0])
    np.testing.assert_allclose(apply_transform(np.array([[1.0, 0.0, 0.0]], np.float32), m), [[1.0, 3.0, 3.0]], atol=1e-6)
    np.testing.assert_allclose(transform_matrix(np.eye(4).ravel()), np.eye(4))
    with pytest.raises(ValueError, match="transform"):
        transform_matrix([1, 2, 3])


@pytest.mark.parametrize("cfg", [SMALL, ModelConfig(name="paper", ngf=8, ndf=8)], ids=["residual_unet", "paper"])
def test_onnx_matches_torch(tmp_path, cfg):
    torch.manual_seed(0)
    generator = build_generator(cfg).eval()
    path = export_onnx(generator, tmp_path / "g.onnx", cfg.in_channels)
    b = wt.generate_batch(2, seed=3)
    condition = b.scan if cfg.in_channels == 1 else torch.cat([b.scan, b.mask], 1)
    report = check_onnx(generator, path, condition, repeats=1)
    assert report["max_abs_diff"] < 1e-4
    with pytest.raises(ValueError, match="onnx"):
        export_onnx(generator, tmp_path / "g.txt", cfg.in_channels)


def test_the_shipped_model_loads_with_weights_only_and_reconstructs(monkeypatch):
    from warp_terrain.inference.reconstructor import pretrained_path

    path = pretrained_path()
    assert path.is_file() and path.stat().st_size < 8 * 2**20  # small enough to ship
    calls = []
    real_load = torch.load
    monkeypatch.setattr(torch, "load", lambda *a, **k: calls.append(k.get("weights_only")) or real_load(*a, **k))
    rec = Reconstructor.load(device="cpu")
    assert calls == [True]
    assert (path.parent / "run_config.yaml").is_file()  # the config it was trained with lies beside it
    height = rec.reconstruct(_scan(seed=11))
    assert height.shape == (121, 121) and np.isfinite(height).all()


def test_reconstruct_command_writes_map_and_preview(tmp_path, capsys):
    from warp_terrain.cli import main

    cloud = tmp_path / "cloud.ply"
    points = _scan(seed=4)
    _write("ply", cloud, points + np.array([0.0, 0.0, 1.9], np.float32))  # a cloud in a ground frame
    out = tmp_path / "map.npz"
    assert main(["reconstruct", str(cloud), "--out", str(out), "--transform", "0,0,-1.9,0,0,0"]) == 0
    with np.load(out) as f:
        assert f["height"].shape == (121, 121) and f["mask"].sum() > 100
        expected = Reconstructor.load(device="cpu").reconstruct(points)
        np.testing.assert_allclose(f["height"], expected, atol=1e-4)
    assert out.with_suffix(".png").stat().st_size > 0
    assert main(["reconstruct", str(tmp_path / "missing.las")]) == 2
    assert "missing.las" in capsys.readouterr().err
