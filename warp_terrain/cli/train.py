"""``python train.py`` / ``warp-terrain train``: compose the run config with Hydra and train.

Hydra parses the overrides (``terrain=octave3 train.steps=500``, ``-m`` sweeps) against the
configs shipped in the package (``warp_terrain.conf``), so the same command works from a
source checkout and from an installed wheel, in any folder.
"""

from __future__ import annotations

import sys

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from ..compose import CONFIG_NAME, CONFIG_PATH, register_configs, to_run_config
from ..plots.callbacks import PaperFigures
from ..training import train
from ..training.report import print_summary

register_configs()


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name=CONFIG_NAME)
def main(cfg: DictConfig) -> float:
    try:
        run = to_run_config(cfg)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    summary = train(run, HydraConfig.get().runtime.output_dir, callbacks=[PaperFigures()])
    if "val_rmse_unobserved" not in summary:  # a non-main rank under torchrun
        return float("nan")
    print_summary(summary)
    return summary["val_rmse_unobserved"]
