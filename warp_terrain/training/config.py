"""The training loop's configuration (the Hydra group ``train/``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..sim.validation import check_finite, require

RESUME_OFF = ("false", "no", "0", "none", "")  # train.resume values that start afresh
RESUME_LATEST = ("true", "yes", "1")  # ... that continue the run folder's latest checkpoint


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
    zero (pix2pix's schedule; 1.0 keeps them constant, as the paper states).
    ``dataset``: empty trains on the live stream; else a folder written by
    ``warp-terrain generate``, cycled over (``training.stream.training_batches``).
    """

    steps: int = 1200
    batch_size: int = 8
    val_every: int = 200
    val_size: int = 32
    log_every: int = 10
    image_every: int = 200
    checkpoint_every: int = 200
    resume: str = "false"
    workers: int = 1
    prefetch: int = 4
    device: str = "auto"
    seed: int = 0
    lr_decay_from: float = 1.0
    threads: int = 0
    progress: bool = True
    dataset: str = ""

    def validate(self) -> None:
        for key in ("steps", "batch_size", "val_every", "val_size", "log_every", "image_every", "checkpoint_every", "prefetch"):
            value = getattr(self, key)
            require(isinstance(value, int) and not isinstance(value, bool) and value >= 1, key, value, "must be an integer >= 1")
        for key in ("workers", "threads", "seed"):
            value = getattr(self, key)
            require(isinstance(value, int) and not isinstance(value, bool) and value >= 0, key, value, "must be an integer >= 0")
        require(self.device in ("auto", "cpu", "cuda") or self.device.startswith("cuda:"), "device", self.device, "must be auto, cpu, cuda or cuda:N")
        require(isinstance(self.dataset, str), "dataset", self.dataset, "must be a folder path or empty (the live stream)")
        if self.dataset:
            require(Path(self.dataset).expanduser().is_dir(), "dataset", self.dataset, "no such folder (write one with `warp-terrain generate`)")
        resume = str(self.resume).strip()
        if resume.lower() not in RESUME_OFF + RESUME_LATEST:
            require(Path(resume).expanduser().exists(), "resume", self.resume, "must be false, true, or an existing run folder or checkpoint file")
        check_finite("lr_decay_from", self.lr_decay_from)
        require(0.0 <= self.lr_decay_from <= 1.0, "lr_decay_from", self.lr_decay_from, "must be in [0, 1]")
