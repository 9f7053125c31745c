"""Datasets on disk: written and read back identical to the stream, manifest, integrity, training."""

import hashlib
import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import run_config, tiny_sim
from omegaconf import OmegaConf

import warp_terrain
from warp_terrain import generate_batch
from warp_terrain.cli import main
from warp_terrain.data.disk import DatasetError, DiskPairs, shard_seed, write_dataset
from warp_terrain.data.stream import batch_seed, make_pair, training_batches

MAPS = ("scan", "mask", "target")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("ds") / "data"
    manifest = write_dataset(out, 5, tiny_sim(noise=0.05), seed=7, shard_size=2, device="cpu")
    return out, manifest


def test_written_dataset_reads_back_identical_to_the_generator(dataset):
    out, manifest = dataset
    pairs = DiskPairs(out)
    assert len(pairs) == 3 and pairs.count == 5 and [s["count"] for s in manifest["shards"]] == [2, 2, 1]
    sim = tiny_sim(noise=0.05)
    for k in range(len(pairs)):
        n = manifest["shards"][k]["count"]
        fresh = generate_batch(n, sim, seed=shard_seed(7, k), device="cpu")
        stream = make_pair(sim, n, batch_seed(7, 0, k), "cpu")  # = batch k of the training stream
        got = pairs[k]
        assert set(got) == set(MAPS)
        for name in MAPS:
            assert got[name].dtype == torch.float32 and got[name].shape == (n, 1, 41, 41)
            assert torch.equal(got[name], getattr(fresh, name)), (k, name)
            assert torch.equal(got[name], stream[name]), (k, name)
    assert torch.equal(pairs.samples([4, 0])["target"][1], pairs[0]["target"][0])


def test_manifest_records_config_seeds_version_shapes_and_hashes(dataset):
    out, manifest = dataset
    on_disk = json.loads((out / "manifest.json").read_text())
    assert on_disk == json.loads(json.dumps(manifest))
    assert on_disk["format"] == "warp-terrain-dataset" and on_disk["format_version"] == 1
    assert on_disk["warp_terrain_version"] == warp_terrain.__version__
    assert on_disk["sim"] == json.loads(json.dumps(asdict(tiny_sim(noise=0.05))))
    assert on_disk["count"] == 5 and on_disk["shard_size"] == 2 and on_disk["seed"] == 7
    assert on_disk["arrays"]["scan"] == {"dtype": "float32", "sample_shape": [1, 41, 41]}
    for k, shard in enumerate(on_disk["shards"]):
        path = out / shard["file"]
        assert shard["seed"] == batch_seed(7, 0, k)
        assert shard["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
        assert shard["bytes"] == path.stat().st_size
        assert shard["shapes"] == {name: [shard["count"], 1, 41, 41] for name in MAPS}
        with np.load(path) as z:  # a plain numpy archive
            assert sorted(z.files) == sorted(MAPS) and z["scan"].dtype == np.float32
    assert DiskPairs(out).sim == tiny_sim(noise=0.05)


def test_same_command_writes_the_same_bytes(dataset, tmp_path):
    _, manifest = dataset
    again = write_dataset(tmp_path / "again", 5, tiny_sim(noise=0.05), seed=7, shard_size=2, device="cpu")
    assert [s["sha256"] for s in again["shards"]] == [s["sha256"] for s in manifest["shards"]]


@pytest.mark.slow
def test_worker_processes_write_the_same_bytes(dataset, tmp_path):
    _, manifest = dataset
    parallel = write_dataset(tmp_path / "parallel", 5, tiny_sim(noise=0.05), seed=7, shard_size=2, device="cpu", workers=2)
    assert [s["sha256"] for s in parallel["shards"]] == [s["sha256"] for s in manifest["shards"]]
    with pytest.raises(ValueError, match="workers"):
        write_dataset(tmp_path / "bad", 5, tiny_sim(noise=0.05), workers=-1)


def _copy(src: Path, dst: Path) -> Path:
    dst.mkdir()
    for p in src.iterdir():
        (dst / p.name).write_bytes(p.read_bytes())
    return dst


def test_corrupt_missing_or_foreign_shards_are_named(dataset, tmp_path):
    out, _ = dataset
    bad = _copy(out, tmp_path / "bad")
    data = bytearray((bad / "shard-00001.npz").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (bad / "shard-00001.npz").write_bytes(bytes(data))
    with pytest.raises(DatasetError, match="shard-00001.npz is corrupt"):
        DiskPairs(bad)
    # without the hash check, loading it still fails clearly (or the bytes were not in an array)
    (bad / "shard-00001.npz").write_bytes(b"not a zip")
    with pytest.raises(DatasetError, match="shard-00001.npz"):
        DiskPairs(bad, verify=False)[1]
    (bad / "shard-00001.npz").unlink()
    with pytest.raises(DatasetError, match="shard-00001.npz is missing"):
        DiskPairs(bad)
    (bad / "manifest.json").unlink()
    with pytest.raises(DatasetError, match="no manifest.json"):
        DiskPairs(bad)
    with pytest.raises(DatasetError, match="no such folder"):
        DiskPairs(tmp_path / "nothing")


def test_refuses_a_non_empty_folder_unless_overwrite(tmp_path):
    out = tmp_path / "d"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    with pytest.raises(DatasetError, match="not empty"):
        write_dataset(out, 1, tiny_sim(noise=0.05), device="cpu")
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    write_dataset(out, 1, tiny_sim(noise=0.05), device="cpu", overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "notes.txt", "shard-00000.npz"]
    with pytest.raises(ValueError, match="count"):
        write_dataset(tmp_path / "e", 0, tiny_sim(noise=0.05), device="cpu")
    assert not (tmp_path / "e").exists()


def test_training_batches_from_a_dataset_cycle_reproducibly(dataset):
    out, _ = dataset
    sim = tiny_sim(noise=0.05)
    # batch size = shard size: the first epoch is the stream itself
    from_disk = list(training_batches(sim, 2, seed=7, rank=0, start=0, stop=7, device="cpu", workers=1, dataset=str(out)))
    stream = list(training_batches(sim, 2, seed=7, rank=0, start=0, stop=2, device="cpu", workers=0))
    assert [int(b["step"]) for b in from_disk] == list(range(7))
    for a, b in zip(from_disk[:2], stream):
        assert all(torch.equal(a[k], b[k]) for k in MAPS)
    # every sample once per epoch; later epochs in another order; any step can be regenerated
    pairs = DiskPairs(out)
    epoch1 = pairs.order(1, seed=7)
    assert sorted(epoch1.tolist()) == list(range(5)) and epoch1.tolist() != list(range(5))
    resumed = next(training_batches(sim, 2, seed=7, rank=0, start=5, stop=6, device="cpu", workers=0, dataset=str(out)))
    assert int(resumed["step"]) == 5 and torch.equal(resumed["target"], from_disk[5]["target"])
    with pytest.raises(ValueError, match="map_size"):
        bigger = tiny_sim(noise=0.05)
        bigger.data.map_size = 61
        training_batches(bigger, 2, 0, 0, 0, 1, "cpu", 0, dataset=str(out))


def test_train_reads_the_dataset_through_config(dataset, tmp_path):
    from warp_terrain.training import train

    out, _ = dataset
    tiny = ["model=unet", "model.ngf=8", "model.ndf=8", "model.unet_depth=3", "data.map_size=41", "terrain.margin=0.5",
            "terrain.amplitude=1.5", "lidar=vlp16", "lidar.azimuth_step_deg=2.0", "data.noise=0.05", "train.batch_size=2", "train.val_size=2",
            "train.workers=0", "train.progress=false", "train.steps=2", f"train.dataset={out}"]
    cfg = run_config(*tiny)
    assert cfg.train.dataset == str(out)
    with pytest.warns(UserWarning, match="different terrain/lidar/data config"):  # the run's terrain (amplitude 1.5 m) is not the dataset's
        summary = train(cfg, tmp_path / "run")
    assert summary["steps"] == 2 and Path(summary["checkpoint"]).is_file()
    assert run_config().train.dataset == ""


def test_generate_command_with_a_run_config(tmp_path, capsys):
    config = tmp_path / "run_config.yaml"
    sim = tiny_sim(noise=0.05)
    OmegaConf.save(OmegaConf.create({"terrain": asdict(sim.terrain), "lidar": asdict(sim.lidar), "data": asdict(sim.data),
                                     "train": {"steps": 3}}), config)
    out = tmp_path / "gen"
    assert main(["generate", "3", "--out", str(out), "--config", str(config), "--terrain", "octave3", "--noise", "0.1",
                 "--seed", "2", "--shard-size", "2", "--json", "--device", "cpu"]) == 0
    manifest = json.loads(capsys.readouterr().out)
    assert manifest["sim"]["terrain"]["name"] == "octave3" and manifest["sim"]["data"]["noise"] == pytest.approx(0.1)
    assert manifest["sim"]["data"]["map_size"] == 41 and manifest["sim"]["lidar"]["name"] == "vlp16"
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "shard-00000.npz", "shard-00001.npz"]
    assert main(["generate", "3", "--out", str(out), "--config", str(config), "--device", "cpu"]) == 2
    assert "not empty" in capsys.readouterr().err
    assert main(["generate", "3", "--out", str(tmp_path / "x"), "--lidar", "nope", "--device", "cpu"]) == 2
    assert not (tmp_path / "x").exists()
