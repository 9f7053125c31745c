"""The run's ``train.log`` tells what happened (config, device, validations, checkpoints, resume,
summary) with the numbers the run records, stdout keeps only the summary; ``validation.png`` is
a labelled figure."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import pytest
import torch
from conftest import ROOT, TINY_RUN

from warp_terrain.core.torchfile import load_checkpoint
from warp_terrain.training.visuals import VALIDATION_COLORBARS, VALIDATION_TITLES, validation_figure

VALIDATION = re.compile(r"step (\d+)/(\d+): validation RMSE on unobserved cells ([\d.]+) m \(best ([\d.]+) m\); "
                        r"nearest-neighbour fill ([\d.]+) m")


def _train(run_dir, *overrides):
    return subprocess.run([sys.executable, str(ROOT / "train.py"), *TINY_RUN, *overrides, f"hydra.run.dir={run_dir}"],
                          cwd=run_dir.parent, capture_output=True, text=True, timeout=300)


@pytest.mark.slow  # two train.py processes
def test_train_log_records_validations_checkpoints_resume_and_summary(tmp_path):
    run = tmp_path / "run"
    out = _train(run, "train.steps=2", "train.val_every=1", "train.checkpoint_every=2")
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.splitlines()[0].startswith("finished 2 steps in ")  # stdout: the summary alone
    assert "[INFO]" not in out.stdout + out.stderr
    summary = json.loads((run / "summary.json").read_text())
    text = (run / "train.log").read_text()
    assert "device cpu" in text
    assert "terrain=octave5 lidar=vlp16 model=unet" in text and "run_config.yaml" in text
    assert f"composed config: {run / '.hydra' / 'config.yaml'}" in text
    assert "training from step 0 of 2 (fresh weights)" in text
    found = [m.groups() for m in VALIDATION.finditer(text)]
    assert [(int(s), int(n)) for s, n, *_ in found] == [(1, 2), (2, 2)]
    *_, (_, _, rmse, best, nn) = found
    assert float(rmse) == pytest.approx(summary["val_rmse_unobserved"], abs=1e-6)
    assert float(best) == pytest.approx(load_checkpoint(run / "checkpoints" / "best.pt")["best"], abs=1e-6)
    assert float(nn) == pytest.approx(summary["nearest_fill_rmse_unobserved"], abs=1e-6)
    assert f"step 2: wrote checkpoint {run / 'checkpoints' / 'latest.pt'}" in text
    assert f"wrote checkpoint {run / 'checkpoints' / 'best.pt'} (new best validation RMSE" in text
    assert "finished 2 steps in " in text and f"validation RMSE on unobserved cells {float(rmse):.6f} m" in text

    resumed = _train(run, "train.steps=3", "train.val_every=1", "train.checkpoint_every=2", "train.resume=true")
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    after = (run / "train.log").read_text()
    assert after.startswith(text)  # appended to
    assert f"resumed from {run / 'checkpoints' / 'latest.pt'} at step 2 of 3 (best validation RMSE so far {float(best):.6f} m)" in after
    (last,) = [m.groups() for m in VALIDATION.finditer(after[len(text):])]
    assert last[:2] == ("3", "3")
    assert float(last[2]) == pytest.approx(json.loads((run / "summary.json").read_text())["val_rmse_unobserved"], abs=1e-6)


def test_validation_figure_has_titles_metre_axes_and_colour_bars():
    g = torch.Generator().manual_seed(0)
    scan, target, prediction = (torch.rand(3, 1, 9, 9, generator=g) for _ in range(3))
    mask = (torch.rand(3, 1, 9, 9, generator=g) > 0.5).float()
    fig = validation_figure(scan, mask, prediction, target, map_cell=0.5, rows=2, step=7)
    panels = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    bars = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert [ax.get_title() for ax in panels] == list(VALIDATION_TITLES) * 2
    assert VALIDATION_TITLES == ("scan", "mask", "prediction", "ground truth", "|error|")
    assert {(ax.get_xlabel(), ax.get_ylabel()) for ax in panels} == {("x (m)", "y (m)")}
    assert {tuple(ax.images[0].get_extent()) for ax in panels} == {(-2.25, 2.25, -2.25, 2.25)}  # 9 cells of 0.5 m
    assert [ax.get_ylabel() for ax in bars] == ["z (m)", "mask (1 = observed)", "z (m)", "z (m)", "|error| (m)"] * 2
    assert VALIDATION_COLORBARS[-1] == "|error| (m)"
    assert "after step 7" in fig.get_suptitle()
    # the error panel shows |prediction - target| of its map, the ground truth panel the target
    error = panels[4].images[0].get_array()
    torch.testing.assert_close(torch.as_tensor(error.T), (prediction[0, 0] - target[0, 0]).abs())
    torch.testing.assert_close(torch.as_tensor(panels[8].images[0].get_array().T), target[1, 0])
