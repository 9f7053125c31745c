"""The ``warp-terrain`` command line: bench JSON, preview PNG, and exit code 2 on bad arguments;
the library functions its thin sub-commands call (map files, a sample as a stage, packaging)."""

import importlib
import json

import numpy as np
import pytest
from conftest import tiny_sim
from pxr import Usd, UsdGeom

from warp_terrain.bench.harness import SEED
from warp_terrain.cli import SUBCOMMANDS, build_parser, main
from warp_terrain.core.geometry import MapGeometry
from warp_terrain.evaluation.calibrate import package_model
from warp_terrain.export import export_sample
from warp_terrain.inference.maps import write_map
from warp_terrain.training import RunConfig

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


_ENV = {"device": "cpu", "device_name": "test CPU", "cpu_count": 2, "warp": "1.0", "torch": "2.0", "python": "3.11",
        "warp_terrain": "0.1.0", "platform": "test"}
_NOISE = {"workload": "noise", "params": {"batch": 8, "size": 257, "octaves": 5}, "median_s": 0.0125,
          "samples_per_s": 8 * 257 * 257 / 0.0125, "heightfields_per_s": 640.0}


def test_bench_table(capsys, monkeypatch):
    """Without --json, stdout is the table of what the benchmarks returned (run here with fixed
    numbers, so the text is known): the header, a ruled table with the noise row in ms and
    M samples/s, and the footer. The command passes the device, --only and --quick through."""
    calls = []

    def fixed(**kwargs):
        calls.append({k: kwargs[k] for k in ("device", "only", "quick")})
        return {"environment": _ENV, "quick": True, "results": {"noise": _NOISE}}

    monkeypatch.setattr("warp_terrain.bench.run_benchmarks", fixed)
    assert main(["bench", "--quick", "--only", "noise", "--device", "cpu"]) == 0
    assert calls == [{"device": "cpu", "only": ["noise"], "quick": True}]
    assert capsys.readouterr().out.splitlines() == [
        "warp-terrain 0.1.0 bench on cpu (test CPU, 2 CPUs)  warp 1.0  torch 2.0  [quick]",
        "",
        "workload  parameters                             median    throughput",
        "--------  -------------------------------------  --------  -------------------------------",
        "noise     8 fBm heightfields 257x257, 5 octaves  12.50 ms  42.27M samples/s (640 fields/s)",
        "",
        "median of repeats after one warm-up call (compilation excluded); device synchronised before each clock read",
        "ours = N x anchor: our throughput over the anchor's on the same work (> 1: ours is faster)",
    ]


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


def test_bench_loader_compares_worker_processes(capsys, monkeypatch):
    """The loader workload pulls the default training stream (batch 8) with 0, 1 and 2 worker
    processes: a stream stands in for the real one here and records what it was asked for. Each
    run opens the stream with its worker count for the start-up batch plus the 2 timed ones
    (--quick), pulls exactly those 3, and reports 8 x 2 pairs over the timed seconds."""
    streams = []

    def stream(sim, batch, seed, rank, start, stop, device, workers, prefetch):
        record = {"sim": sim, "batch": batch, "seed": seed, "range": (start, stop), "device": device, "workers": workers, "pulled": 0}
        streams.append(record)
        for step in range(start, stop):
            record["pulled"] += 1
            yield {"step": step}

    monkeypatch.setattr("warp_terrain.bench.loader.training_batches", stream)
    assert main(["bench", "--json", "--quick", "--only", "loader", "--device", "cpu"]) == 0
    loader = json.loads(capsys.readouterr().out)["results"]["loader"]
    sim = RunConfig().sim()
    assert [r.pop("sim") == sim for r in streams] == [True] * 3
    assert streams == [{"batch": 8, "seed": SEED, "range": (0, 3), "device": "cpu", "workers": w, "pulled": 3} for w in (0, 1, 2)]
    assert loader["params"] == {"batch": 8, "lidar": sim.lidar.name, "map_size": sim.data.map_size, "seed": SEED}
    assert [(r["workers"], r["batches"]) for r in loader["runs"]] == [(0, 2), (1, 2), (2, 2)]
    for r in loader["runs"]:
        assert r["seconds"] > 0 and r["pairs_per_s"] == 8 * 2 / r["seconds"]
    assert loader["pairs_per_s"] == {str(r["workers"]): r["pairs_per_s"] for r in loader["runs"]}


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


def test_the_evaluate_help_names_every_baseline():
    """``--baselines`` lists the fills it accepts: every one of ``BASELINES`` (the harmonic fill was
    once accepted but not listed)."""
    from warp_terrain.evaluation.baselines import BASELINES

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices["evaluate"]
    listed = next(a for a in sub._actions if a.dest == "baselines").help.split("subset of ")[1].split(",")
    assert [name.split(" ")[0] for name in listed[: len(BASELINES)]] == list(BASELINES)


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
