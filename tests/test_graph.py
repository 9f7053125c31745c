"""Replayed batches (``sim/graph.py``) and the allocation arena (``sim/arena.py``): a replay is
``generate_batch`` bit for bit, allocates nothing and reads nothing back; CUDA graph capture
(marked ``gpu``) replays the same batches."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import warp as wp
from conftest import tiny_sim

import warp_terrain as wt
from warp_terrain.sim import arena as arena_module
from warp_terrain.sim.arena import Arena
from warp_terrain.sim.graph import BatchGraph

KEYS = ("heights", "sensor_z", "points", "scan", "mask", "scan_max", "target")


def busy_sim() -> wt.SimConfig:
    """Every stage that allocates: obstacles, landforms, clutter, image noise, range noise."""
    sim = tiny_sim(noise=0.05)
    sim.terrain.cylinders.count_min = sim.terrain.cylinders.count_max = 2
    sim.terrain.pits.count_max = 2
    sim.terrain.tilt.enabled = True
    sim.terrain.landforms.depressions_max = 2
    sim.terrain.clutter.enabled = True
    sim.terrain.clutter.bushes_max = 3
    sim.lidar.range_noise_std, sim.lidar.dropout = 0.02, 0.1
    return sim


def same(a: wt.Batch, b: wt.Batch, keys=KEYS) -> None:
    for key in keys:
        np.testing.assert_array_equal(getattr(a, key).cpu().numpy(), getattr(b, key).cpu().numpy(), err_msg=key)


@pytest.mark.parametrize("make_sim", [tiny_sim, busy_sim], ids=["plain", "busy"])
def test_replayed_batches_equal_generate_batch_bit_for_bit(make_sim):
    sim = make_sim()
    graph = BatchGraph(3, sim, device="cpu")
    assert not graph.capture and not graph.replays
    keys = KEYS + (("target_visible",) if sim.terrain.clutter.enabled else ())
    for seed in (5, 6, 5, -1, 2**40 + 3):  # a seed again, negative and wide seeds masked as generate_batch masks them
        out = graph(seed)
        same(out, wt.generate_batch(3, sim, seed=seed, device="cpu"), keys)
    assert graph.replays and out is graph(7)  # one batch object, its arrays overwritten by each call


def test_a_replay_allocates_nothing_and_reads_nothing_back(monkeypatch):
    graph = BatchGraph(2, busy_sim(), device="cpu")
    graph(1)
    recorded = len(graph.arena.arrays)
    assert recorded > 20
    made = []
    monkeypatch.setattr(wp.array, "numpy", lambda self: pytest.fail("a replay read an array back to the host"))
    for name in ("empty", "zeros", "full", "array", "empty_like", "zeros_like", "clone"):
        real = getattr(wp, name)
        monkeypatch.setattr(wp, name, lambda *a, _real=real, _name=name, **k: (made.append(_name), _real(*a, **k))[1])
    graph(2)
    assert made == [] and len(graph.arena.arrays) == recorded


def test_the_arena_refuses_a_batch_that_changed():
    arena = Arena()
    with arena.run():
        first = arena_module.empty((2, 3), float, "cpu")
        arena_module.upload(np.arange(4, dtype=np.int32), int, "cpu")
        filled = arena_module.full(2, -1.0, float, "cpu")
    filled.fill_(5.0)
    with arena.run():
        assert arena_module.empty((2, 3), float, "cpu") is first
        arena_module.upload(np.arange(4, dtype=np.int32), int, "cpu")
        assert arena_module.full(2, -1.0, float, "cpu") is filled and filled.numpy().tolist() == [-1.0, -1.0]  # filled again
    with pytest.raises(RuntimeError, match=r"array 0 was recorded as \(2, 3\) float32 on cpu, this run asks for \(3, 3\)"):
        with arena.run():
            arena_module.empty((3, 3), float, "cpu")
    with pytest.raises(RuntimeError, match="upload 1 holds other values than when recorded"):
        with arena.run():
            arena_module.empty((2, 3), float, "cpu")
            arena_module.upload(np.arange(1, 5, dtype=np.int32), int, "cpu")
    with pytest.raises(RuntimeError, match="this run asked for 1 arrays, the recorded run for 3"):
        with arena.run():
            arena_module.empty((2, 3), float, "cpu")
    with pytest.raises(RuntimeError, match="asks for more arrays than the 3 recorded"):
        with arena.run():
            arena_module.empty((2, 3), float, "cpu")
            arena_module.upload(np.arange(4, dtype=np.int32), int, "cpu")
            arena_module.full(2, -1.0, float, "cpu")
            arena_module.empty((2, 3), float, "cpu")
    assert arena_module.current_arena() is None


def test_a_world_drawn_per_batch_is_refused():
    sim = tiny_sim()
    sim.data.randomize.enabled = True  # DEM ground: tests/test_dem.py
    with pytest.raises(ValueError, match="data.randomize.enabled=True: draws a new world per batch on the host"):
        BatchGraph(2, sim, device="cpu")


def test_capture_needs_cuda_and_bad_arguments_are_named():
    with pytest.raises(ValueError, match="capture=True: needs a CUDA device, got cpu"):
        BatchGraph(2, tiny_sim(), device="cpu", capture=True)
    with pytest.raises(ValueError, match="batch=0: must be an integer >= 1"):
        BatchGraph(0, tiny_sim(), device="cpu")
    with pytest.raises(ValueError, match="seed=1.5: must be an integer"):
        BatchGraph(1, tiny_sim(), device="cpu")(1.5)


@pytest.mark.gpu
def test_a_captured_graph_replays_generate_batch_on_cuda():
    sim = busy_sim()
    graph = BatchGraph(4, sim, device="cuda")
    assert graph.capture
    first = graph(11)
    assert graph.graph is not None
    same(first, wt.generate_batch(4, sim, seed=11, device="cuda"))
    for seed in (12, 11):
        same(graph(seed), wt.generate_batch(4, sim, seed=seed, device="cuda"))
    side = torch.cuda.Stream()
    with torch.cuda.stream(side):  # replayed on whatever stream is current, ordered with it
        out = graph(13)
        copy = out.target.clone()
    torch.cuda.synchronize()
    np.testing.assert_array_equal(copy.cpu().numpy(), wt.generate_batch(4, sim, seed=13, device="cuda").target.cpu().numpy())


@pytest.mark.parametrize("workers", [0, 1])
def test_the_training_stream_with_capture_gives_the_same_pairs(workers):
    from warp_terrain.data.stream import training_batches

    sim = tiny_sim(noise=0.05)

    def pairs(capture):  # each pair copied before the next is asked for
        return [{k: v.clone() for k, v in p.items()} for p in training_batches(sim, 2, 7, 0, 1, 4, "cpu", workers, capture=capture)]

    plain, replayed = pairs(False), pairs(True)
    assert [int(p["step"]) for p in replayed] == [1, 2, 3]
    for a, b in zip(plain, replayed, strict=True):
        assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    assert not torch.equal(replayed[0]["target"], replayed[1]["target"])  # a new batch each step


def test_train_capture_is_checked_before_any_work(tmp_path):
    from warp_terrain.compose import compose_run

    with pytest.raises(ValueError, match="train.capture=true: a replayed batch needs a fixed world; data.randomize.enabled draws a new one"):
        compose_run(["train.capture=true", "data.randomize.enabled=true"])
    with pytest.raises(ValueError, match="train.capture=true: replays the live stream's batches; train.dataset="):
        compose_run(["train.capture=true", f"train.dataset={tmp_path}"])
    assert compose_run(["train.capture=true"]).train.capture is True
