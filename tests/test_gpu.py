"""CUDA against the CPU (marked ``gpu``: skipped without a CUDA device), and the default device.

Every other test runs on the CPU: ``conftest.py`` sets ``WARP_TERRAIN_DEVICE=cpu``, which
``resolve_device(None)`` honours, so the suite passes unchanged on a GPU machine.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import tiny_sim

import warp_terrain as wt
from warp_terrain.sim.device import DEVICE_ENV, resolve_device


def test_the_default_device_follows_the_environment(monkeypatch):
    monkeypatch.setenv(DEVICE_ENV, "cpu")
    assert resolve_device(None) == "cpu"
    assert wt.generate_batch(1, tiny_sim(), seed=0).scan.device.type == "cpu"
    monkeypatch.setenv(DEVICE_ENV, "tpu")
    with pytest.raises(ValueError, match="device='tpu'"):
        resolve_device(None)


@pytest.mark.gpu
def test_cuda_batches_equal_cpu_batches():
    """Terrain to 1e-5 m; at least 99.99 % of the rays hit on both with points within 1 mm; maps
    where the masks agree within 1 mm."""
    sim = tiny_sim()
    cpu = wt.generate_batch(4, sim, seed=3, device="cpu")
    gpu = wt.generate_batch(4, sim, seed=3, device="cuda")
    assert gpu.scan.device.type == "cuda"
    np.testing.assert_allclose(gpu.heights.cpu().numpy(), cpu.heights.numpy(), atol=1e-5)
    a, b = cpu.points.numpy(), gpu.points.cpu().numpy()
    hit_a, hit_b = np.isfinite(a).all(-1), np.isfinite(b).all(-1)
    assert (hit_a == hit_b).mean() >= 0.9999
    both = hit_a & hit_b
    assert np.abs(a[both] - b[both]).max() < 1e-3
    same = (cpu.mask == gpu.mask.cpu())
    assert same.float().mean() >= 0.999
    torch.testing.assert_close(gpu.target.cpu(), cpu.target, atol=1e-3, rtol=0)


@pytest.mark.slow
def test_no_cuda_driver_warning_on_a_cpu_machine_unless_verbose(tmp_path):
    """Warp's native library warns that it found no NVIDIA driver; on a CPU machine that is
    noise, so it is shown only with WARP_TERRAIN_VERBOSE (everything else it prints still shows)."""
    import os
    import subprocess
    import sys

    import warp as wp

    wp.init()
    if wp.is_cuda_available():
        pytest.skip("a CUDA driver is present: there is nothing to hide")
    code = "import warp_terrain as wt; wt.generate_batch(1, seed=0)"
    env = {k: v for k, v in os.environ.items() if k != "WARP_TERRAIN_VERBOSE"}
    quiet = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert quiet.returncode == 0, quiet.stderr
    assert "CUDA driver" not in quiet.stderr
    loud = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env={**env, "WARP_TERRAIN_VERBOSE": "1"},
                          capture_output=True, text=True, timeout=300)
    assert "Could not find or load the NVIDIA CUDA driver" in loud.stderr + loud.stdout


@pytest.mark.gpu
def test_the_batch_is_made_on_torchs_current_stream():
    """Under a non-default torch stream, the Warp launches of ``generate_batch`` run on that
    stream (``sim/device.py`` ``torch_stream``): torch work queued after them on it reads
    finished maps, identical to those made on the default stream."""
    sim = wt.SimConfig()
    reference = wt.generate_batch(4, sim, seed=3, device="cuda")
    side = torch.cuda.Stream()
    with torch.cuda.stream(side):
        batch = wt.generate_batch(4, sim, seed=3, device="cuda")
        total = batch.target.sum() + batch.scan.sum()  # queued on `side`, behind the launches
    side.synchronize()
    torch.testing.assert_close(batch.target, reference.target, rtol=0, atol=0)
    torch.testing.assert_close(total, reference.target.sum() + reference.scan.sum(), rtol=0, atol=0)

