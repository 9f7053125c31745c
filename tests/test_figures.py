"""The paper's figure kinds and the export-usd command: non-empty PNGs and stages, clear errors."""

from dataclasses import asdict

import numpy as np
import pytest
import torch
from conftest import tiny_sim
from pxr import Usd, UsdGeom

from warp_terrain.cli import main
from warp_terrain.models import Pix2PixModel
from warp_terrain.plots.paper import FIGURE_FILES, prediction_figure

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    """An untrained small U-Net in the training checkpoint format (model + run config)."""
    model = Pix2PixModel(dict(name="unet", ngf=8, ndf=8, unet_depth=3, in_channels=2))
    path = tmp_path_factory.mktemp("ckpt") / "latest.pt"
    torch.save({"model": model.state_dict(), "config": asdict(tiny_sim()), "step": 0}, path)
    return path


def _assert_pngs(folder, names):
    assert sorted(p.name for p in folder.iterdir()) == sorted(names)  # no temporary files left
    for name in names:
        data = (folder / name).read_bytes()
        assert data.startswith(PNG_SIGNATURE) and len(data) > 2000, name


def test_figures_without_a_checkpoint(tmp_path, capsys):
    out = tmp_path / "figs"
    assert main(["figures", "--out", str(out), "--seed", "1", "--dpi", "40", "--device", "cpu"]) == 0
    _assert_pngs(out, [FIGURE_FILES["fig1"], FIGURE_FILES["fig3"]])
    assert "--checkpoint" in capsys.readouterr().err


@pytest.mark.slow
def test_figures_with_a_checkpoint(tmp_path, checkpoint):
    out = tmp_path / "figs"
    assert main(["figures", "--out", str(out), "--checkpoint", str(checkpoint), "--dpi", "40", "--device", "cpu"]) == 0
    _assert_pngs(out, list(FIGURE_FILES.values()))


def test_figures_bad_checkpoint(tmp_path, capsys):
    assert main(["figures", "--out", str(tmp_path / "figs"), "--checkpoint", str(tmp_path / "none.pt"), "--device", "cpu"]) == 2
    assert "none.pt" in capsys.readouterr().err
    assert not (tmp_path / "figs").exists()


def test_predictor_is_any_callable_and_its_shape_is_checked():
    sim = tiny_sim()
    fig = prediction_figure(lambda scan, mask: scan * 0.0, sim, samples=1, device="cpu")
    assert len(fig.axes) >= 3
    with pytest.raises(ValueError, match="predictor"):
        prediction_figure(lambda scan, mask: scan[:, :, :10], sim, samples=1, device="cpu")


def test_export_usd_command(tmp_path, checkpoint):
    out = tmp_path / "sample.usdc"
    png = tmp_path / "sample.png"
    assert main(["export-usd", str(out), "--with-points", "--checkpoint", str(checkpoint), "--terrain", "flat_cylinders",
                 "--png", str(png), "--device", "cpu"]) == 0
    stage = Usd.Stage.Open(str(out))
    terrain = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Terrain"))
    n = len(terrain.GetPointsAttr().Get())
    side = int(round(np.sqrt(n)))
    assert side * side == n and len(terrain.GetFaceVertexCountsAttr().Get()) == 2 * (side - 1) ** 2
    assert len(UsdGeom.Points(stage.GetPrimAtPath("/World/Sensor/LidarPoints")).GetPointsAttr().Get()) > 0
    assert len(UsdGeom.Mesh(stage.GetPrimAtPath("/World/Reconstruction/Map")).GetPointsAttr().Get()) == 41 * 41
    assert stage.GetPrimAtPath("/World/ReconstructionError/Map").IsValid()
    assert png.read_bytes().startswith(PNG_SIGNATURE) and png.stat().st_size > 2000


def test_export_usd_command_bad_suffix(tmp_path, capsys):
    assert main(["export-usd", str(tmp_path / "x.ply"), "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and ".ply" in err
    assert list(tmp_path.iterdir()) == []


def test_a_model_trained_on_dem_ground_is_used_where_its_rasters_are_not(tmp_path):
    """The shipped model trained on a raster of real_data/; on a user's machine that file is
    absent. Its predictor still carries its sensor and maps, and its figures (the obstacle
    settings, which swap in a terrain without rasters) still draw."""
    from warp_terrain.inference.predictor import reconstructor_predictor
    from warp_terrain.inference.reconstructor import Reconstructor
    from warp_terrain.models.config import ModelConfig
    from warp_terrain.models.pix2pix import build_generator
    from warp_terrain.plots.paper import _obstacle_sim
    from warp_terrain.sim import SimConfig

    sim = SimConfig()
    sim.lidar.mount_height = 2.2
    config = {key: asdict(getattr(sim, key)) for key in ("terrain", "lidar", "data")}
    config["terrain"]["dem"]["files"] = [str(tmp_path / "gone.tif")]
    config["data"]["randomize"].update(enabled=True, dem_probability=0.25)
    cfg = ModelConfig(name="unet", in_channels=2, residual=True, ngf=4, unet_depth=3).validate()
    rec = Reconstructor(build_generator(cfg), cfg, meta={"config": config}, device="cpu")
    predictor = reconstructor_predictor(rec)
    assert predictor.sim.lidar.mount_height == 2.2
    obstacles = _obstacle_sim(predictor.sim, "flat_cylinders")
    assert obstacles.terrain.cylinders.count_max > 0 and not obstacles.data.randomize.enabled
