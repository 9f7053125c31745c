"""Models: the Pix2Pix conditional GAN and its generators and discriminator.

Pure torch: nothing here knows the simulator or the training loop.

- `ModelConfig` (config.py): the Hydra structured config of everything below.
- `PaperUNet` (paper_unet.py): the paper's Table 2 generator for 121x121 maps.
- `UNet` (unet.py): a conventional pix2pix U-Net for any size.
- `PatchDiscriminator` (patchgan.py): the conditional 70x70 PatchGAN.
- `GANLoss` (losses.py): vanilla (BCE on logits) or least-squares adversarial loss.
- `scan_noise` (noise.py): a scan's own measurement noise, from its second differences.
- `Pix2PixModel`, `build_model`, `build_generator`, `build_discriminator` (pix2pix.py).
"""

from .config import ModelConfig
from .losses import GANLoss
from .paper_unet import PaperUNet
from .patchgan import PatchDiscriminator
from .pix2pix import Pix2PixModel, build_discriminator, build_generator, build_model
from .unet import UNet

__all__ = [
    "GANLoss",
    "ModelConfig",
    "PaperUNet",
    "PatchDiscriminator",
    "Pix2PixModel",
    "UNet",
    "build_discriminator",
    "build_generator",
    "build_model",
]
