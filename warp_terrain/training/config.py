"""The training run's configuration: ``TrainConfig`` (the Hydra group ``train/``) and ``RunConfig``.

``RunConfig`` is the schema of ``conf/config.yaml``: one structured config per module (terrain,
lidar, data, scans, model, train). Its defaults are what ``python train.py`` composes: the dataclass
defaults are the one source (``conf/`` holds only what differs from them, a test checks).
``validate_run`` checks ranges and consistency and names the offending key.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..core.checks import check_finite, require
from ..data.scans import ScanMixConfig
from ..models.config import ModelConfig
from ..models.presets import model_preset
from ..sim.batch import DataConfig, SimConfig
from ..sim.lidar import LidarConfig, lidar_preset
from ..sim.terrain import TerrainConfig

RESUME_OFF = ("false", "no", "0", "none", "")  # train.resume values that start afresh
RESUME_LATEST = ("true", "yes", "1")  # ... that continue the run folder's latest checkpoint
INIT_PRETRAINED = "pretrained"  # train.init_from value that starts from the model shipped in the package


@dataclass
class TrainConfig:
    """How long to train, on what, and how often to look.

    ``steps`` optimiser steps of ``batch_size`` pairs, each batch freshly generated from
    ``(seed, rank, step)``. Every ``val_every`` steps the fixed validation set (``val_size``
    pairs from seeds disjoint from training) is scored; ``image_every`` steps an image grid is
    logged; ``checkpoint_every`` steps ``latest.pt`` is written (``best.pt`` when validation
    improves). ``resume``: ``"false"``, ``"true"`` (continue the run folder's latest checkpoint)
    or a path to a run folder or checkpoint file. ``workers``: generator processes (0 makes
    batches in the training process; on CUDA generation stays on the device in-process).
    ``lr_decay_from``: fraction of ``steps`` after which both learning rates decay linearly to
    zero (pix2pix's schedule; 1.0 keeps them constant, as the paper states). The defaults are a
    useful run on a 2-core CPU in about five minutes (``train=default``).
    ``init_from``: empty starts from fresh weights; else the generator's weights are taken from a
    model file (``Reconstructor.save``, ``package-model``), a training checkpoint, or
    ``pretrained`` (the model shipped in the package): fine-tuning. Its net must be the run's
    (``models.config.GENERATOR_FIELDS``; a difference is refused before any work); the
    optimisers start afresh. A resumed run takes its weights from its checkpoint instead.
    ``dataset``: empty trains on the live stream; else a folder written by
    ``warp-terrain generate``, cycled over (``data.stream.training_batches``).
    ``capture``: the live stream replays one recorded batch per step (``sim/graph.py``
    ``BatchGraph``: a CUDA graph on CUDA; on the CPU, in each generator process, the same
    launches on the same arrays); needs a fixed world (no ``data.randomize``, fBm terrain).
    ``cell_dropout``: each training input loses a share of its observed cells drawn uniformly in
    ``[0, cell_dropout]`` (``data.cell_dropout``), scored as unobserved cells: the single holes
    the self-check makes at inference (0: off; validation inputs are never thinned).
    """

    steps: int = 1000
    batch_size: int = 8
    val_every: int = 250
    val_size: int = 32
    log_every: int = 10
    image_every: int = 250
    checkpoint_every: int = 250
    resume: str = "false"
    workers: int = 1
    prefetch: int = 4
    device: str = "auto"
    seed: int = 0
    lr_decay_from: float = 0.5
    threads: int = 0
    progress: bool = True
    dataset: str = ""
    capture: bool = False
    init_from: str = ""
    cell_dropout: float = 0.0

    def validate(self, files: bool = True) -> None:
        """Check every field; ``files=False`` does not look for the folder and the model file
        ``dataset`` and ``init_from`` name (a recorded recipe read where they are absent)."""
        for key in ("steps", "batch_size", "val_every", "val_size", "log_every", "image_every", "checkpoint_every", "prefetch"):
            value = getattr(self, key)
            require(isinstance(value, int) and not isinstance(value, bool) and value >= 1, key, value, "must be an integer >= 1")
        for key in ("workers", "threads", "seed"):
            value = getattr(self, key)
            require(isinstance(value, int) and not isinstance(value, bool) and value >= 0, key, value, "must be an integer >= 0")
        require(self.device in ("auto", "cpu", "cuda") or self.device.startswith("cuda:"), "device", self.device, "must be auto, cpu, cuda or cuda:N")
        require(isinstance(self.capture, bool), "capture", self.capture, "must be true or false")
        require(isinstance(self.dataset, str), "dataset", self.dataset, "must be a folder path or empty (the live stream)")
        if self.dataset and files:
            require(Path(self.dataset).expanduser().is_dir(), "dataset", self.dataset, "no such folder (write one with `warp-terrain generate`)")
        require(isinstance(self.init_from, str), "init_from", self.init_from, "must be a model file, a checkpoint, pretrained, or empty")
        if self.init_from and self.init_from != INIT_PRETRAINED and files:
            require(Path(self.init_from).expanduser().is_file(), "init_from", self.init_from,
                    "no such file (a model file, a training checkpoint, or pretrained for the shipped model)")
        resume = str(self.resume).strip()
        if resume.lower() not in RESUME_OFF + RESUME_LATEST:
            require(Path(resume).expanduser().exists(), "resume", self.resume, "must be false, true, or an existing run folder or checkpoint file")
        check_finite("cell_dropout", self.cell_dropout)
        require(0.0 <= self.cell_dropout < 1.0, "cell_dropout", self.cell_dropout, "must be in [0, 1)")
        check_finite("lr_decay_from", self.lr_decay_from)
        require(0.0 <= self.lr_decay_from <= 1.0, "lr_decay_from", self.lr_decay_from, "must be in [0, 1]")


@dataclass
class RunConfig:
    """Everything a training run needs; ``sim()`` is its simulator part."""

    terrain: TerrainConfig = field(default_factory=TerrainConfig)
    lidar: LidarConfig = field(default_factory=lambda: lidar_preset("hdl32e"))
    data: DataConfig = field(default_factory=DataConfig)
    scans: ScanMixConfig = field(default_factory=ScanMixConfig)  # real scans mixed in (data/scans.py)
    model: ModelConfig = field(default_factory=lambda: model_preset("fill_residual"))
    train: TrainConfig = field(default_factory=TrainConfig)

    def sim(self) -> SimConfig:
        return SimConfig(terrain=self.terrain, lidar=self.lidar, data=self.data)


def validate_run(cfg: RunConfig, files: bool = True) -> RunConfig:
    """Check every section and their consistency; the error names the full key. ``files=False``
    does not open the files a config names (DEM rasters, scans, a training set, the weights to
    start from: a recorded recipe read where they are absent)."""
    for section in ("terrain", "lidar", "data", "scans", "model", "train"):
        try:
            getattr(cfg, section).validate(files) if section in ("terrain", "scans", "train") else getattr(cfg, section).validate()
        except ValueError as err:
            raise ValueError(f"{section}.{err}") from None
    if cfg.model.name == "paper" and cfg.data.map_size != 121:
        raise ValueError(f"data.map_size={cfg.data.map_size}: model=paper is Table 2's net for 121x121 maps; use model=unet for other sizes")
    _check_obstacle_room(cfg)
    _check_dem_mix(cfg, files)
    _check_capture(cfg)
    _check_scan_mix(cfg)
    _check_centre_cells(cfg)
    return cfg


def _check_centre_cells(cfg: RunConfig) -> None:
    """A model that centres its input takes each cell's offset from the simulated points."""
    if not cfg.model.centre_cells:
        return
    if cfg.train.dataset:
        raise ValueError(f"model.centre_cells=true: needs each cell's points, which pairs read from disk "
                         f"(train.dataset={cfg.train.dataset!r}) do not keep; train on the live stream")
    if cfg.scans.enabled():
        raise ValueError(f"model.centre_cells=true: real scans mixed in (scans.share={cfg.scans.share}) carry no offsets yet")


def _check_scan_mix(cfg: RunConfig) -> None:
    """Real scans join the live stream, and only a loss that can skip cells can learn from them."""
    if not cfg.scans.enabled():
        return
    if cfg.train.dataset:
        raise ValueError(f"scans.share={cfg.scans.share}: real scans join the live stream; train.dataset={cfg.train.dataset!r} reads pairs from disk")
    if cfg.train.capture:
        raise ValueError(f"scans.share={cfg.scans.share}: a replayed batch (train.capture=true) cannot mix in real scans")
    if cfg.model.gan_mode != "none":
        raise ValueError(f"scans.share={cfg.scans.share}: a real pair's target is unknown off its returns, which the "
                         f"discriminator would learn; use model.gan_mode=none (got {cfg.model.gan_mode!r})")


def _check_capture(cfg: RunConfig) -> None:
    """A replayed batch (``train.capture``) needs the live stream and a fixed world."""
    if not cfg.train.capture:
        return
    if cfg.train.dataset:
        raise ValueError(f"train.capture=true: replays the live stream's batches; train.dataset={cfg.train.dataset!r} reads them from disk")
    if cfg.data.randomize.enabled:
        raise ValueError("train.capture=true: a replayed batch needs a fixed world; data.randomize.enabled draws a new one per batch")
    if cfg.terrain.source != "fbm":
        raise ValueError(f"train.capture=true: a replayed batch needs fBm terrain; terrain.source={cfg.terrain.source!r} cuts windows on the host")


def _check_dem_mix(cfg: RunConfig, files: bool) -> None:
    """A randomised fBm world that mixes in real ground needs rasters that load."""
    mix = cfg.data.randomize
    if not (mix.enabled and mix.dem_probability > 0) or cfg.terrain.source == "dem":
        return
    if not cfg.terrain.dem.files:
        raise ValueError(f"data.randomize.dem_probability={mix.dem_probability}: mixes in real ground: name the rasters in terrain.dem.files")
    try:
        cfg.terrain.dem.validate("dem", load=files)
    except ValueError as err:
        raise ValueError(f"terrain.{err}") from None


def _check_obstacle_room(cfg: RunConfig) -> None:
    """Obstacles need somewhere to stand: ``keep_out`` must leave part of their region free."""
    terrain = cfg.terrain
    if not terrain.has_obstacles():
        return
    region = terrain.obstacle_region or cfg.data.geometry.half_extent
    if terrain.keep_out >= region:
        raise ValueError(
            f"terrain.keep_out={terrain.keep_out}: leaves no room for obstacles in the +-{region:g} m "
            "region around the sensor (lower keep_out or raise terrain.obstacle_region)"
        )
