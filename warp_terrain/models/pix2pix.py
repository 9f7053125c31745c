"""The Pix2Pix model: a generator, a PatchGAN, their losses and optimisers, one training step.

As in pytorch-CycleGAN-and-pix2pix, the model states its nets (`model_names`), losses
(`loss_names`) and visuals (`visual_names`); the training loop (`training.session`) drives it
through `set_input`, `optimize_parameters` and `loss_values`, and adds only the per-cell L1
weights and the learning-rate schedule:

    model = build_model(cfg).to(device)
    for condition, target in batches:
        model.set_input(condition, target)
        losses = model.optimize_parameters()   # dict of detached 0-d tensors, no device sync
    model.loss_values()                        # the same as python floats (syncs once)

Step (pix2pix): D on (condition, prediction.detach()) as fake and (condition, target) as real,
loss_D = (fake + real) / 2; then G with D frozen: loss_G = GAN(D(condition, prediction), real)
+ lambda_l1 * L1(prediction, target), or with `height_loss="l2"` the squared error in place of
L1 (the loss's name stays "l1": the height term). The term may be weighted per pixel (`weight` in
`set_input`), e.g. to weight unobserved cells; without a weight it is the plain mean.
With `uncertainty` the generator's second channel is a log-variance, trained by the Gaussian
NLL of the detached height error (`models.uncertainty`), added to loss_G with the same weights.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
import torch.distributed as dist
from torch import nn
from torch.nn.parallel import DistributedDataParallel

from .config import ModelConfig
from .fill import FillResidualGenerator
from .losses import GANLoss
from .paper_unet import PaperUNet
from .patchgan import PatchDiscriminator
from .uncertainty import gaussian_nll, split_output
from .unet import UNet


def build_generator(cfg: ModelConfig | Mapping) -> nn.Module:
    """`cfg.name`: "paper" -> PaperUNet (Table 2), "unet" -> UNet (pix2pix-style); with
    `cfg.uncertainty` it has one more output channel (the log-variance)."""
    cfg = ModelConfig.coerce(cfg).validate()
    channels = cfg.out_channels + int(cfg.uncertainty)
    inputs = cfg.in_channels + int(cfg.screened_input > 0)  # the screened fill is the last input
    if cfg.name == "paper":
        net = PaperUNet(inputs, channels, cfg.ngf, cfg.norm, cfg.dropout)
    else:
        net = UNet(inputs, channels, cfg.ngf, cfg.unet_depth, cfg.norm, cfg.dropout, cfg.refine)
    if not cfg.residual:
        return net
    if cfg.start_from_fill:
        last = [m for m in net.modules() if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d))][-1]
        nn.init.zeros_(last.weight)
        if last.bias is not None:
            nn.init.zeros_(last.bias)
    return FillResidualGenerator(net, cfg.height_scale_min, cfg.base_fill, cfg.height_reference, cfg.observed_bound,
                                 cfg.screened_input, cfg.observed_bound_noise)


def build_discriminator(cfg: ModelConfig | Mapping) -> nn.Module:
    cfg = ModelConfig.coerce(cfg).validate()
    return PatchDiscriminator(cfg.in_channels, cfg.out_channels, cfg.ndf, cfg.disc_layers, cfg.norm)


class Pix2PixModel:
    """Conditional GAN for condition (B, in_channels, H, W) -> target (B, out_channels, H, W).

    Not an nn.Module (like pix2pix's BaseModel): it owns two nets and two optimisers and
    mirrors the nn.Module calls a loop needs: `to`, `train`, `eval`, `state_dict`,
    `load_state_dict`. Build it on the CPU, then `.to(device)`.
    """

    model_names = ("netG", "netD")
    loss_names = ("discriminator", "generator_gan", "l1")  # + "nll" with uncertainty
    visual_names = ("condition", "prediction", "target")

    def __init__(self, cfg: ModelConfig | Mapping):
        self.cfg = ModelConfig.coerce(cfg).validate()
        self.device = torch.device("cpu")
        self.netG = build_generator(self.cfg)
        self.netD = build_discriminator(self.cfg)
        self.criterion_gan = GANLoss("vanilla" if self.cfg.gan_mode == "none" else self.cfg.gan_mode)
        self.adversarial = self.cfg.gan_mode != "none"  # "none": L1 regression, D untouched
        betas = (self.cfg.beta1, self.cfg.beta2)
        self.optimizer_G = torch.optim.Adam(self.netG.parameters(), lr=self.cfg.lr_g, betas=betas)
        self.optimizer_D = torch.optim.Adam(self.netD.parameters(), lr=self.cfg.lr_d, betas=betas)
        self.optimizers = (self.optimizer_G, self.optimizer_D)
        self.world = 1  # > 1 after distribute()
        self.condition: torch.Tensor | None = None
        self.target: torch.Tensor | None = None
        self.weight: torch.Tensor | None = None
        self.prediction: torch.Tensor | None = None
        self.log_variance: torch.Tensor | None = None  # with cfg.uncertainty
        self.loss_G: torch.Tensor | None = None  # total generator loss of the last step
        self.losses: dict[str, torch.Tensor] = {}  # detached, on the model's device

    # -- data ---------------------------------------------------------------------------
    def set_input(self, condition: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None) -> None:
        """condition (B, in_channels, H, W), target (B, out_channels, H, W), optional weight
        (B, 1, H, W) multiplying the per-pixel L1 term; all on the model's device already."""
        cfg = self.cfg
        if condition.dim() != 4 or condition.shape[1] != cfg.in_channels:
            raise ValueError(f"condition must be (B, {cfg.in_channels}, H, W), got {tuple(condition.shape)}")
        expected = (condition.shape[0], cfg.out_channels, *condition.shape[2:])
        if tuple(target.shape) != expected:
            raise ValueError(f"target must be {expected}, got {tuple(target.shape)}")
        if weight is not None and (weight.dim() != 4 or weight.shape[1] != 1 or weight.shape[2:] != target.shape[2:]):
            raise ValueError(f"weight must be (B, 1, H, W) like the target, got {tuple(weight.shape)}")
        self.condition, self.target, self.weight = condition, target, weight

    def forward(self) -> torch.Tensor:
        self.prediction, self.log_variance = split_output(self.netG(self.condition), self.cfg.uncertainty)
        return self.prediction

    # -- losses -------------------------------------------------------------------------
    @staticmethod
    def l1_loss(
        prediction: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None, power: int = 1
    ) -> torch.Tensor:
        """mean(weight * |prediction - target| ** power); weight None -> the plain mean absolute
        (``power=1``) or squared (``power=2``) error."""
        error = (prediction - target).abs()
        if power == 2:
            error = error.square()
        if weight is not None:
            error = error * weight
        return error.mean()

    def backward_D(self) -> torch.Tensor:
        fake = torch.cat([self.condition, self.prediction.detach()], dim=1)
        real = torch.cat([self.condition, self.target], dim=1)
        loss_fake = self.criterion_gan(self.netD(fake), False)
        loss_real = self.criterion_gan(self.netD(real), True)
        loss_D = 0.5 * (loss_fake + loss_real)
        loss_D.backward()
        return loss_D

    def backward_G(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        if self.adversarial:
            fake = torch.cat([self.condition, self.prediction], dim=1)
            loss_gan = self.criterion_gan(self.netD(fake), True)
        else:
            loss_gan = torch.zeros((), device=self.prediction.device)
        loss_l1 = self.l1_loss(self.prediction, self.target, self.weight, height_loss_power(self.cfg.height_loss))
        self.loss_G = loss_gan + self.cfg.lambda_l1 * loss_l1
        loss_nll = None
        if self.log_variance is not None:
            loss_nll = gaussian_nll(self.log_variance, self.prediction - self.target, self.weight)
            self.loss_G = self.loss_G + loss_nll
        self.loss_G.backward()
        return loss_gan, loss_l1, loss_nll

    def optimize_parameters(self) -> dict[str, torch.Tensor]:
        """One pix2pix step (D then G). Returns detached 0-d tensors (no host sync):
        "discriminator" = loss_D, "generator_gan" = G's adversarial term, "l1" = the height term
        before the lambda_l1 factor (metres for height targets, m^2 with ``height_loss="l2"``), and with uncertainty "nll" =
        the log-variance's Gaussian NLL. `loss_values()` -> floats."""
        self.forward()
        _set_requires_grad(self.netD, True)
        if self.adversarial:
            self.optimizer_D.zero_grad(set_to_none=True)
            loss_D = self.backward_D()
            self.average_gradients(self.netD)
            self.optimizer_D.step()
        else:
            loss_D = torch.zeros((), device=self.prediction.device)

        _set_requires_grad(self.netD, False)  # D is fixed while G trains
        self.optimizer_G.zero_grad(set_to_none=True)
        loss_gan, loss_l1, loss_nll = self.backward_G()
        self.optimizer_G.step()
        _set_requires_grad(self.netD, True)

        self.losses = {
            "discriminator": loss_D.detach(),
            "generator_gan": loss_gan.detach(),
            "l1": loss_l1.detach(),
        }
        if loss_nll is not None:
            self.losses["nll"] = loss_nll.detach()
        return dict(self.losses)

    # -- data parallel ------------------------------------------------------------------------
    @property
    def generator(self) -> nn.Module:
        """The generator itself (unwrapped from DistributedDataParallel if distributed)."""
        return getattr(self.netG, "module", self.netG)

    def distribute(self, device_ids: list[int] | None = None) -> Pix2PixModel:
        """Train data-parallel across the default process group: G is wrapped in
        DistributedDataParallel (its one forward per backward suits DDP); D's gradients are
        averaged by hand after its backward, because the pix2pix D step runs D twice (fake,
        then real) before one backward, which DDP does not allow. Both start from rank 0's
        weights."""
        self.world = dist.get_world_size()
        for tensor in [*self.netD.parameters(), *self.netD.buffers()]:
            dist.broadcast(tensor.data, 0)
        self.netG = DistributedDataParallel(self.netG, device_ids=device_ids)
        return self

    def average_gradients(self, net: nn.Module) -> None:
        if self.world == 1:
            return
        for p in net.parameters():
            if p.grad is not None:
                dist.all_reduce(p.grad)
                p.grad /= self.world

    def loss_values(self) -> dict[str, float]:
        """The last step's losses as python floats (one device sync)."""
        if not self.losses:
            return {}
        values = torch.stack(list(self.losses.values())).tolist()
        return dict(zip(self.losses.keys(), values))

    # -- outputs ------------------------------------------------------------------------
    def get_current_visuals(self) -> dict[str, torch.Tensor]:
        """The last step's batch: condition, prediction (detached), target."""
        prediction = None if self.prediction is None else self.prediction.detach()
        return {"condition": self.condition, "prediction": prediction, "target": self.target}

    def predict(self, condition: torch.Tensor) -> torch.Tensor:
        """The height (B, 1, H, W) from the generator in eval mode (no dropout, running
        batch-norm statistics), no grad. The previous train/eval mode is restored afterwards."""
        return self.predict_with_uncertainty(condition)[0]

    def predict_with_uncertainty(self, condition: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """``(height, log-variance or None)`` as `predict`."""
        generator = self.generator
        was_training = generator.training
        generator.eval()
        try:
            with torch.no_grad():
                return split_output(generator(condition), self.cfg.uncertainty)
        finally:
            generator.train(was_training)

    # -- nn.Module-like plumbing ----------------------------------------------------------
    def train(self, mode: bool = True) -> Pix2PixModel:
        self.netG.train(mode)
        self.netD.train(mode)
        return self

    def eval(self) -> Pix2PixModel:
        return self.train(False)

    @property
    def training(self) -> bool:
        return self.netG.training

    def to(self, device: torch.device | str) -> Pix2PixModel:
        """Move nets, loss buffers and optimiser state; later inputs must be on `device`."""
        device = torch.device(device)
        self.netG.to(device)
        self.netD.to(device)
        self.criterion_gan.to(device)
        for optimizer in self.optimizers:
            for state in optimizer.state.values():
                for key, value in state.items():
                    if isinstance(value, torch.Tensor) and key != "step":
                        state[key] = value.to(device)
        self.device = device
        return self

    def parameters(self):
        yield from self.netG.parameters()
        yield from self.netD.parameters()

    def state_dict(self) -> dict:
        """Both nets, both optimisers and the config (a plain dict): `torch.save` it and
        `torch.load(..., weights_only=True)` reads it back."""
        return {
            "config": self.cfg.to_dict(),
            "netG": self.generator.state_dict(),
            "netD": self.netD.state_dict(),
            "optimizer_G": self.optimizer_G.state_dict(),
            "optimizer_D": self.optimizer_D.state_dict(),
        }

    def load_state_dict(self, state: Mapping, strict: bool = True) -> None:
        """Load the nets and, where present, the optimisers (an inference-only checkpoint
        may hold just "netG"). The stored config is not applied: build the model from it
        first (`Pix2PixModel.from_state_dict`)."""
        self.generator.load_state_dict(state["netG"], strict=strict)
        if "netD" in state:
            self.netD.load_state_dict(state["netD"], strict=strict)
        if "optimizer_G" in state:
            self.optimizer_G.load_state_dict(state["optimizer_G"])
        if "optimizer_D" in state:
            self.optimizer_D.load_state_dict(state["optimizer_D"])

    @classmethod
    def from_state_dict(cls, state: Mapping, device: torch.device | str = "cpu") -> Pix2PixModel:
        """Rebuild from a checkpoint's stored config, load it, move it to `device`."""
        model = cls(ModelConfig.coerce(state["config"]))
        model.load_state_dict(state)
        return model.to(device)


def height_loss_power(height_loss: str) -> int:
    """The exponent of ``model.height_loss``: 1 for ``"l1"``, 2 for ``"l2"``."""
    return 2 if height_loss == "l2" else 1


def build_model(cfg: ModelConfig | Mapping) -> Pix2PixModel:
    """The Pix2Pix model for `cfg` (a ModelConfig, dict or Hydra DictConfig), on the CPU."""
    return Pix2PixModel(cfg)


def _set_requires_grad(net: nn.Module, flag: bool) -> None:
    for p in net.parameters():
        p.requires_grad_(flag)
