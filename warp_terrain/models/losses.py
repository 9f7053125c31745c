"""The adversarial loss, as pix2pix's `GANLoss`: the target label tensor is built for the caller.

`vanilla` is the paper's cGAN objective (eq. 1-2): binary cross-entropy on the
discriminator's logits (BCEWithLogits, numerically safer than sigmoid + BCE). `lsgan` is the
least-squares GAN: mean squared error of the raw outputs against the labels.
"""

from __future__ import annotations

import torch
from torch import nn


class GANLoss(nn.Module):
    """`loss(prediction, target_is_real)`: mean loss of a logit map against all-real/all-fake."""

    def __init__(self, gan_mode: str = "vanilla", target_real_label: float = 1.0, target_fake_label: float = 0.0):
        super().__init__()
        if gan_mode == "vanilla":
            self.loss = nn.BCEWithLogitsLoss()
        elif gan_mode == "lsgan":
            self.loss = nn.MSELoss()
        else:
            raise ValueError(f"unknown gan_mode {gan_mode!r}: expected vanilla or lsgan")
        self.register_buffer("real_label", torch.tensor(float(target_real_label)))
        self.register_buffer("fake_label", torch.tensor(float(target_fake_label)))

    def target_tensor(self, prediction: torch.Tensor, target_is_real: bool) -> torch.Tensor:
        label = self.real_label if target_is_real else self.fake_label
        return label.to(prediction.dtype).expand_as(prediction)

    def forward(self, prediction: torch.Tensor, target_is_real: bool) -> torch.Tensor:
        return self.loss(prediction, self.target_tensor(prediction, target_is_real))
