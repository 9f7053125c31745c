"""A refused training run says why in one line naming the key, and leaves no folder behind."""

from __future__ import annotations

import subprocess
import sys

import pytest
from conftest import ROOT, TINY_RUN

pytestmark = pytest.mark.slow  # a train.py process per case


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("train.batch_size=10000000", "train.batch_size=10000000: needs about"),
        ("train.resume=true", "train.resume=true: no checkpoint"),
        ("train.device=cuda", "train.device=cuda: CUDA is not available"),
    ],
)
def test_a_refused_run_names_the_key_and_leaves_no_folder(tmp_path, override, key):
    import warp as wp

    wp.init()
    if override == "train.device=cuda" and wp.is_cuda_available():
        pytest.skip("this machine has CUDA")
    run_dir = tmp_path / "run"
    out = subprocess.run([sys.executable, str(ROOT / "train.py"), *TINY_RUN, override, f"hydra.run.dir={run_dir}"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert out.returncode == 2, out.stderr[-2000:]
    assert "Traceback" not in out.stderr
    assert out.stderr.strip().splitlines()[-1].startswith(f"error: {key}"), out.stderr[-2000:]
    assert not run_dir.exists()
