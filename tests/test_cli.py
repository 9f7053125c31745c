"""The ``warp-terrain`` command line: bench JSON, preview PNG, and exit code 2 on bad arguments."""

import json

import pytest

from warp_terrain.cli import build_parser, main

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


def test_bench_loader_compares_worker_processes(capsys):
    assert main(["bench", "--json", "--quick", "--only", "loader"]) == 0
    report = json.loads(capsys.readouterr().out)
    loader = report["results"]["loader"] if "results" in report else report["loader"]
    assert [r["workers"] for r in loader["runs"]] == [0, 1, 2]
    assert all(r["pairs_per_s"] > 0 for r in loader["runs"])
