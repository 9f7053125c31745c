"""The model's configuration: one flat dataclass, usable as a Hydra structured config.

Plain types only (no enums, no nested objects), so that `conf/model/*.yaml` can override any
field and a checkpoint can store it as a plain dict (`dataclasses.asdict`) that
`torch.load(weights_only=True)` accepts.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields

from ..core.checks import require
from .fill import BASE_FILLS, FILL_ERROR_STATISTICS, HEIGHT_REFERENCES

GENERATORS = ("paper", "unet")
NORMS = ("batch", "instance", "none")
GAN_MODES = ("vanilla", "lsgan", "none")
#: the height term of the generator loss: "l1" (pix2pix's mean absolute error) or "l2" (mean
#: squared error: its minimiser is the conditional mean, what RMSE scores)
HEIGHT_LOSSES = ("l1", "l2")


#: the fields that make a generator what it is (its layers, inputs and outputs); a run that starts
#: from another run's weights (``train.init_from``) must agree on every one. The rest (losses,
#: learning rates, the discriminator) may change.
#: Generator fields that hold no weight: ``package-model`` may set them on a trained file and a
#: run may start from a file that differs in them (``train.init_from``).
UNWEIGHTED_FIELDS = ("observed_bound_noise",)
GENERATOR_FIELDS = ("name", "in_channels", "out_channels", "ngf", "unet_depth", "refine", "norm", "dropout", "residual",
                    "height_scale_min", "base_fill", "height_reference", "observed_bound", "observed_bound_noise", "screened_input",
                    "uncertainty")


@dataclass
class ModelConfig:
    """Generator, discriminator, losses and optimisers of the Pix2Pix model.

    Defaults are the paper's (Table 1: lambda 100, Adam lr 2e-4 for both nets, beta1 0.5) and
    pix2pix's (ngf = ndf = 64, 3-layer 70x70 PatchGAN, batch norm, decoder dropout 0.5).
    """

    name: str = "paper"  # generator: "paper" (Table 2's U-Net) | "unet" (pix2pix-style U-Net)
    in_channels: int = 1  # condition channels (e.g. 2 for scan + observation mask)
    out_channels: int = 1  # predicted image channels (1: a height map in metres; see `uncertainty`)
    ngf: int = 64  # generator filters in the first layer (64 = Table 2 exactly)
    ndf: int = 64  # discriminator filters in the first layer
    disc_layers: int = 3  # PatchGAN stride-2 layers (3 = the 70x70 PatchGAN)
    unet_depth: int = 7  # "unet" only: down-sampling steps (input padded to a multiple of 2**depth)
    # "unet" only: full-resolution 3x3 conv layers after the U-Net (ngf filters, over its last
    # features and its input), so a correction can change single cells; 0: pix2pix's U-Net
    refine: int = 0
    norm: str = "batch"  # "batch" | "instance" | "none"
    dropout: float = 0.5  # dropout on the innermost decoder blocks, as pix2pix (0 disables)
    gan_mode: str = "vanilla"  # "vanilla" (the paper's BCE cGAN) | "lsgan" | "none" (L1 only)
    lambda_l1: float = 100.0  # weight of the height term (L1, or L2 with height_loss="l2") in the generator loss
    # the height term: "l1" (pix2pix's, the paper's: the per-cell median) | "l2" (squared error, per
    # cell the conditional mean: RMSE's optimum, so the few cells far from the scan, where errors
    # are metres, count as much as they weigh in the RMSE)
    height_loss: str = "l1"
    lr_g: float = 2e-4
    lr_d: float = 2e-4
    beta1: float = 0.5
    beta2: float = 0.999
    residual: bool = False  # predict a correction to a push-pull fill (needs in_channels=2)
    unobserved_weight: float = 1.0  # L1 weight of unobserved cells relative to observed ones
    # residual only: the net sees heights divided by each map's spread of observed heights (their
    # standard deviation, at least this many metres) and its correction is scaled back, so one net
    # serves reliefs of centimetres and of metres alike; 0 feeds it metres
    height_scale_min: float = 0.0
    # residual only: weight each map's loss by 1 / its observed-height spread (as the scaling above,
    # at least height_scale_min metres), so a rough 4 m hillside does not drown a 5 cm meadow
    relief_relative_loss: bool = False
    # residual only: the classical fill the net corrects: "push_pull" (a normalised-convolution
    # pyramid) | "biharmonic" (the thin plate, as skimage's inpaint_biharmonic; models/biharmonic.py)
    # | "plane_biharmonic" (the thin plate about the observed cells' least-squares plane, plus the plane)
    base_fill: str = "push_pull"
    # residual only: the net sees heights relative to the "mean" observed height or to the observed
    # cells' least-squares "plane" (slope-robust: a tilted window looks level to the net)
    height_reference: str = "mean"
    # residual only: the most (m) the correction may move an observed cell (bound * tanh(c / bound));
    # 0 leaves observed cells free
    observed_bound: float = 0.0
    # with observed_bound: each map's bound is at least this many times its scan's own noise
    # (models/noise.py: from second differences of neighbouring observed cells), so a noisy scan
    # may be denoised while a clean one keeps observed_bound; 0: observed_bound for every map
    observed_bound_noise: float = 0.0
    # residual only: > 0 gives the net a second fill as a third input channel, the thin plate
    # screened by this k (1 / cells) towards the mean observed height: it returns to the mean
    # about 1 / k cells from the scan, where the base fill runs the slope on; 0: no second fill
    screened_input: float = 0.0
    # residual only: weight each map's loss by 1 / the base fill's mean error on its unobserved
    # cells (at least 1 cm; with height_loss="l2" by 1 / its mean squared error), so the net
    # learns to improve on the fill on every map, not only on the maps where the fill errs by metres
    fill_relative_loss: bool = False
    # with fill_relative_loss: the base fill's error a map's loss is divided by, the "mean" of its
    # unobserved cells' errors or their "median" (pits and ditches, a few cells erring by metres,
    # then do not make a map count less)
    fill_relative_statistic: str = "mean"
    # residual only: the net's last layer starts at zero, so the untrained model is the base fill
    # exactly and training only adds what improves on it
    start_from_fill: bool = False
    # the generator also predicts each cell's log-variance of its height error (a second output
    # channel, trained by the Gaussian NLL of the detached error: the height is learnt as without it)
    uncertainty: bool = False
    # the net sees each observed cell's height moved from its returns' mean position to the cell's
    # centre (models/centring.py; the stream then carries each cell's mean offset): an input of
    # the run, not a layer, so a run may switch it on from weights trained without it
    centre_cells: bool = False

    def validate(self) -> ModelConfig:
        """Raise ValueError naming the first bad field; return self so calls can chain."""
        for key, allowed in (("name", GENERATORS), ("norm", NORMS), ("gan_mode", GAN_MODES), ("height_loss", HEIGHT_LOSSES)):
            require(getattr(self, key) in allowed, key, getattr(self, key), f"expected one of {', '.join(allowed)}")
        for key in ("in_channels", "out_channels", "ngf", "ndf", "disc_layers"):
            require(_is_int(getattr(self, key)) and getattr(self, key) > 0, key, getattr(self, key), "expected a positive integer")
        require(self.in_channels in (1, 2), "in_channels", self.in_channels, "inputs are the scan (1) or the scan and its mask (2)")
        require(self.out_channels == 1, "out_channels", self.out_channels, "the generator predicts one height map (1)")
        require(_is_int(self.unet_depth) and self.unet_depth >= 2, "unet_depth", self.unet_depth, "expected an integer >= 2")
        require(_is_int(self.refine) and self.refine >= 0, "refine", self.refine, "expected an integer >= 0 (full-resolution layers)")
        require(self.refine == 0 or self.name == "unet", "refine", self.refine, "only the unet generator has a refine head")
        for key in ("lr_g", "lr_d"):
            require(_is_number(getattr(self, key)) and getattr(self, key) > 0, key, getattr(self, key), "expected a positive learning rate")
        require(_is_number(self.lambda_l1) and self.lambda_l1 >= 0, "lambda_l1", self.lambda_l1, "expected a number >= 0")
        require(_is_number(self.unobserved_weight) and self.unobserved_weight > 0, "unobserved_weight", self.unobserved_weight,
                "expected a number > 0")
        require(_is_number(self.height_scale_min) and 0.0 <= self.height_scale_min < float("inf"), "height_scale_min",
                self.height_scale_min, "expected a finite number >= 0 (metres; 0 disables the scaling)")
        require(self.base_fill in BASE_FILLS, "base_fill", self.base_fill, f"expected one of {', '.join(BASE_FILLS)}")
        require(self.height_reference in HEIGHT_REFERENCES, "height_reference", self.height_reference,
                f"expected one of {', '.join(HEIGHT_REFERENCES)}")
        require(_is_number(self.observed_bound) and 0.0 <= self.observed_bound < float("inf"), "observed_bound",
                self.observed_bound, "expected a finite number >= 0 (metres; 0 leaves observed cells free)")
        require(_is_number(self.observed_bound_noise) and 0.0 <= self.observed_bound_noise < float("inf"), "observed_bound_noise",
                self.observed_bound_noise, "expected a finite number >= 0 (times the scan's noise; 0: observed_bound alone)")
        require(not self.observed_bound_noise or self.observed_bound > 0, "observed_bound_noise", self.observed_bound_noise,
                "needs model.observed_bound > 0 (the bound it widens)")
        require(_is_number(self.screened_input) and 0.0 <= self.screened_input < float("inf"), "screened_input",
                self.screened_input, "expected a finite number >= 0 (1 / cells; 0: no second fill)")
        require(not self.screened_input or self.residual, "screened_input", self.screened_input,
                "needs residual=true (the second fill is an input of the residual generator)")
        require(not self.relief_relative_loss or (self.residual and self.height_scale_min > 0), "relief_relative_loss",
                self.relief_relative_loss, "needs residual=true and height_scale_min > 0 (the spread's floor)")
        require(not self.fill_relative_loss or self.residual, "fill_relative_loss", self.fill_relative_loss,
                "needs residual=true (only a residual generator has a fill to compare with)")
        require(self.fill_relative_statistic in FILL_ERROR_STATISTICS, "fill_relative_statistic", self.fill_relative_statistic,
                f"expected one of {', '.join(FILL_ERROR_STATISTICS)}")
        require(not self.start_from_fill or self.residual, "start_from_fill", self.start_from_fill,
                "needs residual=true (only a residual generator has a fill to start from)")
        require(not self.residual or self.in_channels == 2, "residual", self.residual,
                "the fill needs the mask: set in_channels=2 (scan and mask)")
        for key in ("dropout", "beta1", "beta2"):
            require(_is_number(getattr(self, key)) and 0.0 <= getattr(self, key) < 1.0, key, getattr(self, key), "expected a number in [0, 1)")
        return self

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def coerce(cls, cfg: ModelConfig | Mapping) -> ModelConfig:
        """Accept a ModelConfig, a plain dict or a Hydra DictConfig (any Mapping).

        Unknown keys are an error (a typo in an override should not pass silently).
        """
        if isinstance(cfg, cls):
            return cfg
        if not isinstance(cfg, Mapping):
            raise TypeError(f"expected ModelConfig or a mapping, got {type(cfg).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(str(k) for k in cfg.keys() if k not in known)
        if unknown:
            raise ValueError(f"ModelConfig: unknown field(s) {', '.join(unknown)}")
        return cls(**{k: cfg[k] for k in cfg.keys()})


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and value == value
