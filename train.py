"""Train the Pix2Pix terrain reconstructor on an endless Warp-generated stream.

    python train.py                                   # a useful run on a CPU in ~15 minutes
    python train.py experiment=paper_octave3_noise10  # the paper's experiment, full schedule
    python train.py -m terrain=octave3,octave5 data.noise=0.05,0.10   # a sweep

Compose the config, hand it to warp_terrain; nothing else happens here.
"""

import sys

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from warp_terrain.config import register_configs, to_run_config
from warp_terrain.training import train
from warp_terrain.training.report import print_summary

register_configs()


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def main(cfg: DictConfig) -> float:
    try:
        run = to_run_config(cfg)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    summary = train(run, HydraConfig.get().runtime.output_dir)
    if "val_rmse_unobserved" not in summary:  # a non-main rank under torchrun
        return float("nan")
    print_summary(summary)
    return summary["val_rmse_unobserved"]


if __name__ == "__main__":
    main()
