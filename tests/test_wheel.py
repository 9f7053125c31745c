"""The wheel, installed (not editable) and used from an empty folder, works: every command finds
its presets and configs inside the package, not in a source checkout.

The wheel is built from a copy of the sources (``pip wheel --no-deps``) and installed with
``pip install --no-deps --target``; the commands then run with only that folder on
``PYTHONPATH`` (the test environment provides the dependencies), in a folder with nothing in it.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("pyproject.toml", "README.md", "warp_terrain", "kernels", "conf")

pytestmark = pytest.mark.slow


def _pip(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "pip", *args, "-q", "--disable-pip-version-check"], check=True, timeout=300,
                   capture_output=True, text=True)


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    base = tmp_path_factory.mktemp("wheel")
    src = base / "src"
    src.mkdir()
    for name in SOURCES:
        path = ROOT / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            shutil.copy2(path, src / name)
    _pip("wheel", str(src), "--no-deps", "--no-build-isolation", "-w", str(base / "dist"))
    wheels = list((base / "dist").glob("warp_terrain-*.whl"))
    assert len(wheels) == 1, wheels
    _pip("install", "--no-deps", "--target", str(base / "site"), str(wheels[0]))
    return base / "site"


def _run(site: Path, cwd: Path, *args: str, timeout: int = 600) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(site)}
    out = subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert out.returncode == 0, f"{args}: exit {out.returncode}\n{out.stdout[-2000:]}\n{out.stderr[-2000:]}"
    return out


def test_the_installed_package_is_the_wheel(installed, tmp_path):
    out = _run(installed, tmp_path, "-c", "import warp_terrain, warp_terrain.conf, warp_terrain.kernels as k; "
               "print(warp_terrain.__file__); print(k.__file__); print(warp_terrain.__version__)")
    package, kernels, version = out.stdout.split()
    assert Path(package).is_relative_to(installed) and Path(kernels).is_relative_to(installed)
    assert version == "0.1.0"


def test_commands_work_from_an_empty_folder(installed, tmp_path):
    cli = ("-m", "warp_terrain.cli")
    _run(installed, tmp_path, *cli, "generate", "4", "--out", "data", "--terrain", "negative_obstacles", "--lidar", "vlp16", "--shard-size", "2")
    assert sorted(p.name for p in (tmp_path / "data").iterdir()) == ["manifest.json", "shard-00000.npz", "shard-00001.npz"]
    _run(installed, tmp_path, *cli, "preview", "--terrain", "all", "--out", "preview.png")
    assert (tmp_path / "preview.png").stat().st_size > 0
    _run(installed, tmp_path, *cli, "figures", "--out", "figures")
    assert {p.name for p in (tmp_path / "figures").iterdir()} == {"fig1_octaves.png", "fig3_scan_noise.png"}
    out = _run(installed, tmp_path, *cli, "evaluate", "--pretrained", "--quick", "--settings", "octave5,flat_cylinders",
               "--noise", "0", "--baselines", "nearest", "--json")
    assert '"model"' in out.stdout and '"nearest"' in out.stdout
    tiny = ["model=unet", "model.ngf=4", "model.ndf=4", "model.unet_depth=3", "data.map_size=41", "lidar=vlp16",
            "lidar.azimuth_step_deg=4.0", "train.steps=2", "train.batch_size=2", "train.val_size=2", "train.workers=0",
            "train.progress=false", "hydra.run.dir=run"]
    _run(installed, tmp_path, *cli, "train", *tiny)
    assert (tmp_path / "run" / "checkpoints" / "latest.pt").is_file()
    assert not (tmp_path / "conf").exists()  # nothing was looked up in (or written to) a conf/ folder here
