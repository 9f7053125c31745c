"""The ``warp-terrain`` command line: bench JSON, preview PNG, and exit code 2 on bad arguments;
the library functions its thin sub-commands call (map files, a sample as a stage, packaging)."""

import importlib
import json

import numpy as np
import pytest
from conftest import tiny_sim
from pxr import Usd, UsdGeom

from warp_terrain.cli import SUBCOMMANDS, build_parser, main
from warp_terrain.core.geometry import MapGeometry
from warp_terrain.evaluation.calibrate import package_model
from warp_terrain.export import export_sample
from warp_terrain.inference.maps import write_map

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def test_bench_json_quick_noise(capsys):
    assert main(["bench", "--json", "--quick", "--only", "noise", "--device", "cpu"]) == 0
    out = capsys.readouterr().out
    report = json.loads(out)  # stdout holds only the JSON
    noise = report["results"]["noise"]
    assert set(report["results"]) == {"noise"}
    assert report["environment"]["device"] == "cpu"
    assert report["environment"]["warp"] and report["environment"]["torch"]
    assert noise["samples_per_s"] > 0 and noise["median_s"] > 0
    assert noise["params"]["octaves"] == 5


def test_bench_table(capsys):
    assert main(["bench", "--quick", "--only", "noise", "--device", "cpu"]) == 0
    out = capsys.readouterr().out
    assert "noise" in out and "samples/s" in out


def test_preview_writes_png(tmp_path, capsys):
    out = tmp_path / "preview.png"
    assert main(["preview", "--out", str(out), "--terrain", "octave3", "--seed", "3", "--device", "cpu", "--dpi", "40"]) == 0
    data = out.read_bytes()
    assert data.startswith(PNG_SIGNATURE) and len(data) > 1000
    assert [p.name for p in tmp_path.iterdir()] == ["preview.png"]  # no temporary file left behind


def test_preview_missing_folder(tmp_path, capsys):
    missing = tmp_path / "no_such_folder"
    assert main(["preview", "--out", str(missing / "x.png"), "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and str(missing) in err
    assert len(err.strip().splitlines()) == 1
    assert not missing.exists()


def test_preview_unknown_terrain(tmp_path, capsys):
    assert main(["preview", "--out", str(tmp_path / "x.png"), "--terrain", "moon_craters", "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "moon_craters" in err and "octave5" in err
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize(
    "argv",
    [
        [],
        ["frobnicate"],
        ["bench", "--only", "noise,warp_drive"],
        ["bench", "--device", "tpu"],
        ["preview"],
        ["preview", "--out", "x.png", "--seed", "one"],
    ],
)
def test_bad_arguments_exit_2(argv, capsys):
    assert main(argv) == 2
    assert "error" in capsys.readouterr().err


def test_preview_rejects_non_png(tmp_path, capsys):
    assert main(["preview", "--out", str(tmp_path / "x.jpg"), "--device", "cpu"]) == 2
    assert "x.jpg" in capsys.readouterr().err


def test_parser_lists_subcommands():
    help_text = build_parser().format_help()
    assert "bench" in help_text and "preview" in help_text


@pytest.mark.slow
def test_bench_loader_compares_worker_processes(capsys):
    assert main(["bench", "--json", "--quick", "--only", "loader"]) == 0
    report = json.loads(capsys.readouterr().out)
    loader = report["results"]["loader"] if "results" in report else report["loader"]
    assert [r["workers"] for r in loader["runs"]] == [0, 1, 2]
    assert all(r["pairs_per_s"] > 0 for r in loader["runs"])


@pytest.mark.parametrize("group", ["bench", "data", "evaluate", "figures", "model"])
def test_each_command_module_adds_and_runs_its_commands(group):
    module = importlib.import_module(f"warp_terrain.cli.{group}")
    adders = [name for name in dir(module) if name.startswith("add_")]
    assert adders
    for name in adders:
        assert getattr(module, name) in SUBCOMMANDS
        assert callable(getattr(module, "cmd_" + name[len("add_"):]))


def test_every_subcommand_is_in_the_help():
    help_text = build_parser().format_help()
    for name in ("train", "bench", "preview", "figures", "export-usd", "generate", "evaluate", "reconstruct",
                 "export-onnx", "package-model"):
        assert name in help_text


def test_write_map_round_trip(tmp_path):
    g = MapGeometry(5, 0.5)
    result = {"height": np.arange(25, dtype=np.float32).reshape(5, 5), "mask": np.ones((5, 5), np.float32),
              "uncertainty": np.full((5, 5), 0.1, np.float32)}
    out = write_map(tmp_path / "map.npz", result, g)
    assert out == tmp_path / "map.npz"
    with np.load(out) as f:
        assert sorted(f.files) == ["height", "map_cell", "mask", "uncertainty"]
        np.testing.assert_array_equal(f["height"], result["height"])
        assert f["map_cell"].dtype == np.float32 and float(f["map_cell"]) == 0.5
    assert [p.name for p in tmp_path.iterdir()] == ["map.npz"]  # no temporary file left behind


@pytest.mark.parametrize(
    "name, result, match",
    [
        ("map.npy", {"height": np.zeros((5, 5)), "mask": np.zeros((5, 5))}, "npz"),
        ("map.npz", {"height": np.zeros((5, 5))}, "mask"),
        ("map.npz", {"height": np.zeros((5, 5)), "mask": np.zeros((5, 5)), "extra": np.zeros((5, 5))}, "extra"),
        ("map.npz", {"height": np.zeros((4, 4)), "mask": np.zeros((5, 5))}, "height"),
    ],
)
def test_write_map_rejects_before_writing(tmp_path, name, result, match):
    with pytest.raises(ValueError, match=match):
        write_map(tmp_path / name, result, MapGeometry(5, 0.5))
    assert list(tmp_path.iterdir()) == []


def test_export_sample_with_a_predictor(tmp_path):
    sim = tiny_sim()
    sim.data.augment = True
    out = export_sample(tmp_path / "s.usda", sim, seed=2, predictor=lambda scan, mask: scan * 0.0, device="cpu")
    assert sim.data.augment  # the caller's config is left as it was
    stage = Usd.Stage.Open(str(out))
    assert len(UsdGeom.Mesh(stage.GetPrimAtPath("/World/Reconstruction/Map")).GetPointsAttr().Get()) == 41 * 41
    assert not stage.GetPrimAtPath("/World/Sensor/LidarPoints").IsValid()


def test_export_sample_rejects_before_any_work(tmp_path):
    with pytest.raises(ValueError, match="suffix"):
        export_sample(tmp_path / "s.ply", tiny_sim(), device="cpu")
    with pytest.raises(ValueError, match="SimConfig"):
        export_sample(tmp_path / "s.usda", {"data": {}}, device="cpu")
    assert list(tmp_path.iterdir()) == []


def test_package_model_checks_its_arguments(tmp_path):
    with pytest.raises(ValueError, match="calibrate=-1"):
        package_model(tmp_path / "ckpt.pt", tmp_path / "out.pt", calibrate=-1)
    with pytest.raises(ValueError, match="folder does not exist"):
        package_model(tmp_path / "ckpt.pt", tmp_path / "missing" / "out.pt")
    with pytest.raises(ValueError, match="does not exist"):
        package_model(tmp_path / "ckpt.pt", tmp_path / "out.pt")
