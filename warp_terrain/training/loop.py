"""The training loop: pulls batches from the stream, steps the model, logs to TensorBoard,
scores the fixed validation set against a nearest-neighbour fill, and checkpoints.

It drives a ``Pix2PixModel`` (nets, losses and visuals are the model's) through the phases in
``session.py``; what it logs beyond its own scalars and image grids comes in through
``callbacks`` (figures live in ``plots``).
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence

from tqdm.auto import tqdm

from ..data.stream import training_batches
from . import session
from .checkpoint import LATEST
from .config import RunConfig


def train(cfg: RunConfig, run_dir: str | os.PathLike, callbacks: Sequence = ()) -> dict:
    """Train ``cfg.model`` on the stream described by ``cfg``; write everything under ``run_dir``.

    Returns a summary: final and best validation RMSE on unobserved cells, the nearest-neighbour
    fill's RMSE on the same set, wall time and paths. Under ``torchrun`` every rank trains on its
    own stream and rank 0 validates, logs and checkpoints (see ``distributed.py``).
    ``callbacks``: objects whose ``on_finish(writer, model, cfg, device, step)`` runs on rank 0 at the
    end (``plots.callbacks.PaperFigures`` logs the paper's figures; ``python train.py`` passes it).
    """
    tc = cfg.train
    run = session.setup(cfg, run_dir)
    batches = training_batches(run.sim, tc.batch_size, tc.seed, run.ranks.rank, run.start, tc.steps, run.device, tc.workers, tc.prefetch,
                               dataset=tc.dataset, capture=tc.capture, scans=cfg.scans,
                               offsets=cfg.model.centre_cells)
    bar = tqdm(total=tc.steps, initial=run.start, disable=not (tc.progress and run.ranks.main), desc="train", unit="step", dynamic_ncols=True)
    started = time.perf_counter()
    run.model.train()
    for step in range(run.start, tc.steps):
        session.step(run, batches, step)
        done = step + 1
        if _due(done, tc.log_every, tc.steps):
            session.log(run, done, bar)
        if _due(done, tc.val_every, tc.steps):
            session.validate(run, done)
            session.keep_best(run, done)
        if _due(done, tc.image_every, tc.steps):
            session.log_image(run, done)
        if _due(done, tc.checkpoint_every, tc.steps):
            session.save(run, LATEST, done)
        bar.update(1)
    bar.close()
    return session.finish(run, callbacks, started)


def _due(done: int, every: int, steps: int) -> bool:
    """Whether a task done every ``every`` steps (and after the last) is due after ``done`` steps."""
    return done % every == 0 or done == steps
