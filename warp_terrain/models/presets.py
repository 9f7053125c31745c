"""The model presets, as data: the Hydra group ``model`` is registered from this table.

- ``paper``: the paper's generator (Table 2) and training hyper-parameters (Table 1): the
  ``ModelConfig`` defaults.
- ``paper_small``: Table 2's generator topology at a quarter of its width (ngf 16: 2.6 M
  parameters instead of 42 M), so a run trains on a CPU in minutes. Same losses and optimisers.
- ``unet``: a conventional pix2pix U-Net generator (any map size), same losses and optimisers.
- ``fill_residual``: our model and the training default: a U-Net that sees the scan's push-pull
  fill and the observation mask and predicts a correction to the fill (heights relative to the
  mean observed height), with unobserved cells weighted up in the L1 loss. Same PatchGAN and
  optimisers as the paper. See the README, "Ablation".
"""

from __future__ import annotations

import copy

from .config import ModelConfig

MODEL_PRESETS: dict[str, ModelConfig] = {
    "paper": ModelConfig(),
    "paper_small": ModelConfig(ngf=16, ndf=16),
    "unet": ModelConfig(name="unet", unet_depth=7),
    "fill_residual": ModelConfig(name="unet", in_channels=2, residual=True, unobserved_weight=3.0, ngf=16, ndf=16, unet_depth=6),
}


def model_preset(name: str) -> ModelConfig:
    """A fresh copy of the model preset ``name``."""
    if name not in MODEL_PRESETS:
        raise ValueError(f"model={name!r}: unknown model preset; choose from {', '.join(sorted(MODEL_PRESETS))}")
    return copy.deepcopy(MODEL_PRESETS[name])
