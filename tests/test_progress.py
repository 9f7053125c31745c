"""``evaluate``, ``generate`` and ``bench`` show a tqdm bar on stderr (stdout keeps the JSON);
``--quiet`` shows neither the bar nor the progress lines."""

from __future__ import annotations

import json
from dataclasses import asdict

import pytest
from conftest import tiny_sim
from omegaconf import OmegaConf

from warp_terrain.cli import main


def _bar_done(err: str, what: str, total: int, unit: str) -> bool:
    """Whether ``err`` shows the finished bar ``what: 100%|...| total/total [... unit/s]``."""
    return any(f"{what}: 100%" in part and f"{total}/{total} [" in part and unit in part for part in err.split("\r"))


def test_bench_shows_a_bar_on_stderr_and_only_json_on_stdout(capsys):
    assert main(["bench", "--json", "--quick", "--only", "noise", "--device", "cpu"]) == 0
    out, err = capsys.readouterr()
    assert set(json.loads(out)["results"]) == {"noise"}
    assert _bar_done(err, "bench", 1, "workload"), err
    assert "bench noise on cpu (quick) ..." in err  # the progress lines still show, above the bar


def test_generate_shows_a_bar_per_shard(tmp_path, capsys):
    config = tmp_path / "run_config.yaml"
    sim = tiny_sim()
    OmegaConf.save(OmegaConf.create({"terrain": asdict(sim.terrain), "lidar": asdict(sim.lidar), "data": asdict(sim.data)}), config)
    assert main(["generate", "3", "--out", str(tmp_path / "gen"), "--config", str(config), "--shard-size", "2", "--json", "--device", "cpu"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["count"] == 3
    assert _bar_done(err, "generate", 2, "shard"), err
    assert "shard-00001.npz: 1 pairs" in err
    assert main(["generate", "3", "--out", str(tmp_path / "quiet"), "--config", str(config), "--shard-size", "2", "--device", "cpu", "-q"]) == 0
    out, err = capsys.readouterr()
    assert out == "" and err == f"wrote 3 pairs in 2 shards to {tmp_path / 'quiet'}\n"  # the result, no bar, no lines


@pytest.mark.parametrize("quiet", [False, True])
def test_evaluate_shows_a_bar_per_test_set_unless_quiet(capsys, quiet):
    argv = ["evaluate", "--quick", "--size", "2", "--json", "--settings", "flat_cylinders", "--noise", "0,0.1",
            "--baselines", "nearest", "--device", "cpu"]
    assert main(argv + (["--quiet"] if quiet else [])) == 0
    out, err = capsys.readouterr()
    assert [s["setting"] for s in json.loads(out)["settings"]] == ["flat_cylinders/noise0", "flat_cylinders/noise0.1"]
    if quiet:
        assert err == ""
    else:
        assert _bar_done(err, "evaluate", 2, "set"), err
        assert "flat_cylinders/noise0.1: 2 samples generated" in err
