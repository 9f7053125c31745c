"""Faults a user or a machine can cause: outputs escaping their folder, batches that cannot fit."""

from __future__ import annotations

import io
import os
import types

import pytest

from warp_terrain.core.paths import file_name, output_path
from warp_terrain.sim import SimConfig, generate_batch, memory
from warp_terrain.sim.batch import terrain_size


# ------------------------------------------------------------------ outputs stay in their folder
@pytest.mark.parametrize("name", ["../escape.png", "../../etc/passwd", "/tmp/abs.png", "a/../../b.png"])
def test_output_path_refuses_names_that_escape(tmp_path, name):
    with pytest.raises(ValueError, match="escapes its folder"):
        output_path(tmp_path / "run", name)


def test_output_path_refuses_a_symlink_pointing_out(tmp_path):
    (tmp_path / "run").mkdir()
    os.symlink(tmp_path, tmp_path / "run" / "link")
    with pytest.raises(ValueError, match="escapes"):
        output_path(tmp_path / "run", "link", "x.png")


def test_output_path_accepts_names_inside(tmp_path):
    assert output_path(tmp_path, "figures", "a.png") == tmp_path / "figures" / "a.png"
    assert output_path(tmp_path, "a/./b.png") == tmp_path / "a/./b.png"


@pytest.mark.parametrize("text, expected", [("octave5_noise0.05.png", "octave5_noise0.05.png"),
                                            ("../../x", "_.._x"), ("/etc/passwd", "_etc_passwd"), ("..", "_"), ("a b\n", "a_b_")])
def test_file_name_makes_one_safe_component(text, expected):
    assert file_name(text) == expected
    assert "/" not in file_name(text) and not file_name(text).startswith(".")


# ------------------------------------------------------------------ memory is checked before allocation
def test_the_estimate_covers_what_a_batch_allocates():
    sim = SimConfig()
    batch = generate_batch(2, sim, seed=0)
    allocated = sum(a.capacity for a in batch.warp_arrays.values())
    estimate = memory.batch_bytes(2, terrain_size(sim), sim.lidar.num_rays, sim.data.map_size)
    assert allocated <= estimate <= 2 * allocated, (allocated, estimate)


def test_a_batch_that_cannot_fit_fails_before_any_work(monkeypatch):
    calls = []
    monkeypatch.setattr(memory, "available_bytes", lambda device: 64 * 2**20)
    monkeypatch.setattr("warp_terrain.sim.batch.make_terrains", lambda *a, **k: calls.append(a))
    with pytest.raises(ValueError, match=r"^batch=1000: needs about 1\.\d\d GiB on cpu .* but 64\.0 MiB is free; lower the batch size"):
        generate_batch(1000, SimConfig(), seed=0)
    assert calls == []  # nothing was generated


def test_a_huge_batch_is_refused_on_this_machine():
    with pytest.raises(ValueError, match="lower the batch size"):
        generate_batch(10**8, SimConfig(), seed=0)


MEMINFO = "MemTotal:       16384000 kB\nMemFree:          512000 kB\nMemAvailable:    8192000 kB\nBuffers:  1 kB\n"


def test_available_memory_is_the_kernels_memavailable(monkeypatch):
    """The host's free memory is /proc/meminfo's MemAvailable (kB, so x 1024), not MemFree or
    MemTotal; without /proc, the available pages x the page size; None if neither is known.
    A GPU's is Warp's ``free_memory`` (0: unknown)."""
    opened = []

    def meminfo(path, *args, **kwargs):
        opened.append(path)
        return io.StringIO(MEMINFO)

    monkeypatch.setattr(memory, "open", meminfo, raising=False)
    assert memory.available_bytes("cpu") == 8192000 * 1024
    assert opened == ["/proc/meminfo"]

    def missing(path, *args, **kwargs):
        raise FileNotFoundError(path)

    monkeypatch.setattr(memory, "open", missing, raising=False)
    monkeypatch.setattr(memory.os, "sysconf", {"SC_AVPHYS_PAGES": 3000, "SC_PAGE_SIZE": 4096}.__getitem__)
    assert memory.available_bytes("cpu") == 3000 * 4096

    def unknown(name):
        raise ValueError(f"unrecognized configuration name {name}")

    monkeypatch.setattr(memory.os, "sysconf", unknown)
    assert memory.available_bytes("cpu") is None

    free = {"cuda:0": 123 * 2**20, "cuda:1": 0}
    monkeypatch.setattr(memory.wp, "get_device", lambda device: types.SimpleNamespace(free_memory=free[device]))
    assert memory.available_bytes("cuda:0") == 123 * 2**20
    assert memory.available_bytes("cuda:1") is None


@pytest.mark.skipif(not os.path.exists("/proc/meminfo"), reason="reads Linux's /proc/meminfo")
def test_available_memory_on_this_host_is_between_two_readings_of_memavailable():
    def mem_available() -> int:
        with open("/proc/meminfo", encoding="ascii") as f:
            return next(int(line.split()[1]) * 1024 for line in f if line.startswith("MemAvailable:"))

    before = mem_available()
    free = memory.available_bytes("cpu")
    after = mem_available()
    slack = 256 * 2**20  # the training run beside the tests allocates and frees between readings
    assert min(before, after) - slack <= free <= max(before, after) + slack
