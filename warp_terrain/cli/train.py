"""``python train.py`` / ``warp-terrain train``: compose the run config with Hydra and train.

Hydra parses the overrides (``terrain=octave3 train.steps=500``, ``-m`` sweeps) against the
configs shipped in the package (``warp_terrain.conf``), so the same command works from a
source checkout and from an installed wheel, in any folder.
"""

from __future__ import annotations

import logging
import shutil
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from ..compose import CONFIG_NAME, CONFIG_PATH, register_configs, to_run_config
from ..plots.callbacks import PaperFigures
from ..training import train
from ..training.report import print_summary

register_configs()
log = logging.getLogger("warp_terrain.training")

#: What Hydra writes into a run folder before the run starts.
HYDRA_FILES = {".hydra", "train.log", "main.log"}


def _remove_if_only_hydra(run_dir: Path) -> None:
    """Remove a refused run's folder if it holds nothing but what Hydra wrote into it."""
    if run_dir.is_dir() and {p.name for p in run_dir.iterdir()} <= HYDRA_FILES:
        shutil.rmtree(run_dir, ignore_errors=True)


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name=CONFIG_NAME)
def main(cfg: DictConfig) -> float:
    try:
        run = to_run_config(cfg)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        _remove_if_only_hydra(Path(HydraConfig.get().runtime.output_dir))
        sys.exit(2)
    hydra_cfg = HydraConfig.get()
    run_dir = Path(hydra_cfg.runtime.output_dir)
    composed = f"; composed config: {run_dir / hydra_cfg.output_subdir / 'config.yaml'}" if hydra_cfg.output_subdir else ""
    log.info("overrides: %s%s", " ".join(hydra_cfg.overrides.task) or "none", composed)
    try:
        summary = train(run, run_dir, callbacks=[PaperFigures()])
    except ValueError as err:  # refused before any work (memory, device, resume): one line, no folder left
        print(f"error: {err}", file=sys.stderr)
        _remove_if_only_hydra(run_dir)
        sys.exit(2)
    if "val_rmse_unobserved" not in summary:  # a non-main rank under torchrun
        return float("nan")
    print_summary(summary)
    return summary["val_rmse_unobserved"]
