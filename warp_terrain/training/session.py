"""One training run in phases: ``setup``, then per step ``step``, ``log``, ``validate``,
``keep_best``, ``log_image`` and ``save``, then ``finish``; ``loop.train`` calls them in order.

``setup`` builds a ``TrainingRun``: the ranks and device, the seeded model (resumed from a
checkpoint if asked), the fixed validation set and its nearest-neighbour baseline, and the
TensorBoard writer. The phases read it and keep in it what changes during the run (the best
and latest validation scores, the latest validation prediction, the throughput counters).
Rank 0 alone validates, logs and writes files; on other ranks those phases do nothing.

Rank 0 also tells the Python logger ``warp_terrain.training`` (INFO) what happens: the config in
one line, the device, a resume, each validation (step, RMSE on unobserved cells, the best so far,
the nearest-neighbour fill's), each checkpoint written and the final summary. ``train.py``
sends it to ``RUN_DIR/train.log`` (``conf/hydra/job_logging/run_log.yaml``); called as a
library, it goes wherever the caller's logging sends it (nowhere by default).
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf
from torch.utils.tensorboard import SummaryWriter

from ..core.torchfile import atomic_save, load_checkpoint
from ..data.cell_dropout import drop_observed_cells
from ..data.seeds import batch_seed
from ..data.stream import validation_set
from ..evaluation.baselines import nearest_fill
from ..evaluation.metrics import calibration, masked_rmse
from ..inference.reconstructor import Reconstructor
from ..models import Pix2PixModel, build_generator, build_model
from ..models.centring import centre_cells
from ..models.config import GENERATOR_FIELDS, UNWEIGHTED_FIELDS
from ..models.fill import fill_relative_weight, loss_weight_map, widen_to_screened_input
from ..models.inputs import model_input
from ..models.pix2pix import height_loss_power
from ..models.uncertainty import standard_deviation
from ..sim.batch import SimConfig, terrain_size
from ..sim.device import resolve_device
from ..sim.memory import check_batch_fits
from ..sim.terrain import scratch_bytes
from .checkpoint import BEST, LATEST, remove_stale_temporaries, resolve_resume, rng_state, set_rng_state
from .config import INIT_PRETRAINED, RunConfig
from .distributed import NullWriter, Ranks, close_ranks, init_ranks
from .files import save_figure_png, write_text
from .scalars import DeferredScalars
from .visuals import map_grid, validation_figure

logger = logging.getLogger("warp_terrain.training")


def lr_factor(step: int, steps: int, decay_from: float) -> float:
    """pix2pix's schedule: constant, then linear to zero over the last ``1 - decay_from`` of the run."""
    start = decay_from * steps
    if decay_from >= 1.0 or step < start:
        return 1.0
    return max(0.0, 1.0 - (step - start) / max(steps - start, 1.0))


def predict_in_chunks(model, condition: torch.Tensor, chunk: int = 16) -> tuple[torch.Tensor, torch.Tensor | None]:
    """``(heights, log-variances or None)`` of ``condition``, ``chunk`` maps at a time."""
    outs = [model.predict_with_uncertainty(condition[i : i + chunk]) for i in range(0, condition.shape[0], chunk)]
    log_variance = None if outs[0][1] is None else torch.cat([v for _, v in outs])
    return torch.cat([h for h, _ in outs]), log_variance


@dataclass
class Throughput:
    """Since the last log: seconds spent waiting for batches, seconds in whole steps (the wait
    included), and training pairs stepped on."""

    wait: float = 0.0
    busy: float = 0.0
    pairs: int = 0


@dataclass
class TrainingRun:
    """A run between ``setup`` and ``finish``.

    ``start``: the first step to take (0, or the resumed checkpoint's step). ``best``: the best
    validation RMSE on unobserved cells so far (inf before the first). ``val``: the fixed
    validation pairs (one pair on ranks other than 0, which never score them), ``unobserved``
    their cells to score, ``val_condition`` the model's input for them and ``nn_rmse`` the
    nearest-neighbour fill's RMSE on them. ``base_lrs``: each optimiser's learning rate before
    the schedule's factor, by ``id``. ``relief_floor``: ``loss_weight_map``'s (the model's
    ``height_scale_min`` with ``relief_relative_loss``, else 0). ``rmse`` and ``prediction``: the
    latest validation score and prediction (nan and None before the first).
    """

    cfg: RunConfig
    run_dir: Path
    ranks: Ranks
    device: str
    sim: SimConfig
    model: Pix2PixModel
    start: int
    best: float
    val: dict[str, torch.Tensor]
    unobserved: torch.Tensor
    val_condition: torch.Tensor
    nn_rmse: float
    writer: SummaryWriter | NullWriter
    base_lrs: dict[int, float]
    relief_floor: float
    rmse: float = math.nan
    prediction: torch.Tensor | None = None
    meter: Throughput = field(default_factory=Throughput)
    scalars: DeferredScalars | None = None  # the losses, logged without a device sync (``scalars.py``)

    @property
    def ckpt_dir(self) -> Path:
        return self.run_dir / "checkpoints"

    @property
    def image_dir(self) -> Path:
        return self.run_dir / "images"


def setup(cfg: RunConfig, run_dir: str | os.PathLike) -> TrainingRun:
    """Everything before the first step, in this order: the device and ranks, a check that a batch
    fits the device, a check that ``train.resume`` has something to resume (each refusal names
    its key and comes before any folder is made), the run folders, CPU threads, the torch and numpy seeds, the model (its
    random initial weights), the resumed checkpoint's weights, step, best score and RNG states
    (``train.resume``), ``run_config.yaml``, the validation set and the TensorBoard writer."""
    tc = cfg.train
    run_dir = Path(run_dir)
    try:  # errors name the key the user sets
        device = resolve_device(None if tc.device == "auto" else tc.device)
    except ValueError as err:
        raise ValueError(f"train.device={tc.device}: {str(err).split(': ', 1)[-1]}") from None
    ranks, device = init_ranks(device)
    sim = cfg.sim()
    try:
        check_batch_fits(tc.batch_size, terrain_size(sim), sim.lidar.num_rays, sim.data.map_size, device, scratch_bytes(sim.terrain))
    except ValueError as err:
        raise ValueError(f"train.batch_size={tc.batch_size}: {str(err).split(': ', 1)[-1]}") from None
    resolve_resume(tc.resume, run_dir)  # a resume with nothing to resume fails here, before any folder is made
    initial = initial_weights(cfg)  # so does a train.init_from whose net is not the run's
    for d in (run_dir / "checkpoints", run_dir / "images"):
        d.mkdir(parents=True, exist_ok=True)
    _seed(cfg, device)
    if ranks.main:
        logger.info("run folder %s; config (in full: run_config.yaml): %s", run_dir, describe_config(cfg))
        logger.info("device %s%s; %d torch threads", _device_name(device), f"; {ranks.world} ranks" if ranks.distributed else "",
                 torch.get_num_threads())

    model = build_model(cfg.model).to(device)
    if initial is not None:  # a resumed run's checkpoint replaces these weights next
        model.generator.load_state_dict(initial)
    if ranks.distributed:
        model.distribute([ranks.local_rank] if device.startswith("cuda") else None)
    start, best = _resume(model, cfg, run_dir, ranks)
    if ranks.main:
        if start or math.isfinite(best):
            logger.info("resumed from %s at step %d of %d (best validation RMSE so far %.6f m)",
                     resolve_resume(tc.resume, run_dir), start, tc.steps, best)
        else:
            logger.info("training from step 0 of %d (%s)", tc.steps, f"weights from {tc.init_from}" if initial is not None else "fresh weights")
        write_text(run_dir / "run_config.yaml", OmegaConf.to_yaml(OmegaConf.structured(cfg)))

    val = validation_set(sim, tc.val_size if ranks.main else 1, device, offsets=cfg.model.centre_cells)
    if cfg.model.centre_cells:  # what the model will see of a cloud (``Reconstructor``)
        val["scan"] = centre_cells(val["scan"], val["mask"], val.pop("offset"), cfg.data.map_cell)
    unobserved = val["mask"] == 0
    nn_rmse = masked_rmse(nearest_fill(val["scan"], val["mask"]), val["target"], unobserved)
    val_condition = model_input(val["scan"], val["mask"], cfg.model.in_channels)
    if ranks.main:
        logger.info("validation set: %d maps, %.1f %% of cells observed; nearest-neighbour fill RMSE on unobserved cells %.6f m",
                 val["mask"].shape[0], 100.0 * float((~unobserved).float().mean()), nn_rmse)

    writer = SummaryWriter(log_dir=str(run_dir / "tensorboard"), purge_step=start if start else None) if ranks.main else NullWriter()
    return TrainingRun(
        cfg=cfg,
        run_dir=run_dir,
        ranks=ranks,
        device=device,
        sim=sim,
        model=model,
        start=start,
        best=best,
        val=val,
        unobserved=unobserved,
        val_condition=val_condition,
        nn_rmse=nn_rmse,
        writer=writer,
        base_lrs={id(model.optimizer_G): cfg.model.lr_g, id(model.optimizer_D): cfg.model.lr_d},
        relief_floor=cfg.model.height_scale_min if cfg.model.relief_relative_loss else 0.0,
        scalars=DeferredScalars(writer.add_scalar, "loss"),
    )


def describe_config(cfg: RunConfig) -> str:
    """The run config in one line: the choices that tell runs apart."""
    t, m, d, tc = cfg.terrain, cfg.model, cfg.data, cfg.train
    return (f"terrain={t.name} lidar={cfg.lidar.name} model={m.name} (in_channels={m.in_channels}, residual={m.residual}, "
            f"uncertainty={m.uncertainty}) map={d.map_size}x{d.map_size} cells of {d.map_cell:g} m noise={d.noise:g} "
            f"steps={tc.steps} batch_size={tc.batch_size} val_size={tc.val_size} val_every={tc.val_every} "
            f"checkpoint_every={tc.checkpoint_every} seed={tc.seed} resume={tc.resume} dataset={tc.dataset or 'live stream'}")


def _device_name(device: str) -> str:
    """``device`` with the GPU's name when it is one."""
    if device.startswith("cuda") and torch.cuda.is_available():
        return f"{device} ({torch.cuda.get_device_name(torch.device(device))})"
    return device


def _seed(cfg: RunConfig, device: str) -> None:
    """CPU threads (``train.threads``, or on the CPU the cores the generator workers leave) and
    the torch and numpy seeds (``train.seed``)."""
    tc = cfg.train
    threads = tc.threads or (max(1, (os.cpu_count() or 1) - tc.workers) if device == "cpu" else 0)
    if threads:
        torch.set_num_threads(threads)
    torch.manual_seed(tc.seed)
    np.random.seed(tc.seed)


def initial_weights(cfg: RunConfig) -> dict[str, torch.Tensor] | None:
    """The generator weights ``train.init_from`` names (None if it is empty), read with
    ``weights_only=True``; a ``ValueError`` naming the key and every generator field
    (``GENERATOR_FIELDS``) in which the file's net differs from the run's."""
    source = cfg.train.init_from
    if not source:
        return None
    try:
        rec = Reconstructor.load(None if source == INIT_PRETRAINED else source, device="cpu", tta=False, self_check=False)
    except ValueError as err:
        raise ValueError(f"train.init_from={source}: {err}") from None
    theirs, ours = rec.model_config, cfg.model
    widen = theirs.screened_input == 0 and ours.screened_input > 0  # the run adds the second fill: a zero column
    free = set(UNWEIGHTED_FIELDS) | ({"screened_input"} if widen else set())  # no weight: a run may change them
    differ = [f"{key}={getattr(theirs, key)!r} (the run: {getattr(ours, key)!r})" for key in GENERATOR_FIELDS
              if getattr(theirs, key) != getattr(ours, key) and key not in free]
    if differ:
        raise ValueError(f"train.init_from={source}: its generator is not the run's: model.{', model.'.join(differ)}")
    state = rec.generator.state_dict()
    return widen_to_screened_input(state, build_generator(ours)) if widen else state


def _resume(model: Pix2PixModel, cfg: RunConfig, run_dir: Path, ranks: Ranks) -> tuple[int, float]:
    """``(first step, best score)``: ``(0, inf)``, or the checkpoint's after loading its weights
    and RNG states into ``model`` and this process. Rank 0 first removes a killed run's
    half-written checkpoint files."""
    if ranks.main:
        remove_stale_temporaries(run_dir / "checkpoints")
    resume_from = resolve_resume(cfg.train.resume, run_dir)
    if resume_from is None:
        return 0, math.inf
    state = load_checkpoint(resume_from)
    model.load_state_dict(state["model"])
    set_rng_state(state["rng"])
    return int(state["step"]), float(state["best"])


#: seed offset of ``train.cell_dropout``'s draws (with the run's seed and the step)
CELL_DROPOUT_SEED = 0xD209
#: the least base-fill error (m) a map's loss is divided by with ``model.fill_relative_loss``
FILL_ERROR_FLOOR = 0.01


def step(run: TrainingRun, batches: Iterator[dict], step: int) -> None:
    """Optimiser step ``step``: take the next batch from ``batches`` (it must be batch ``step``),
    set the learning rates to the schedule's (``lr_factor``) and step the model on it. The time
    spent waiting for the batch and in the whole step goes into ``run.meter``."""
    cfg, model = run.cfg, run.model
    t0 = time.perf_counter()
    batch = next(batches)
    if int(batch["step"]) != step:
        raise RuntimeError(f"stream out of order: expected step {step}, got {int(batch['step'])}")
    t1 = time.perf_counter()
    factor = lr_factor(step, cfg.train.steps, cfg.train.lr_decay_from)
    for opt in model.optimizers:
        for g in opt.param_groups:
            g["lr"] = run.base_lrs[id(opt)] * factor
    batch = {k: v.to(run.device, non_blocking=True) for k, v in batch.items() if k != "step"}
    if "offset" in batch:  # model.centre_cells: the cells moved to their centres, as a cloud's are
        batch["scan"] = centre_cells(batch["scan"], batch["mask"], batch.pop("offset"), cfg.data.map_cell)
    if cfg.train.cell_dropout > 0:  # single holes in the rings, as the self-check makes them (per step: resumable)
        batch["scan"], batch["mask"] = drop_observed_cells(batch["scan"], batch["mask"], cfg.train.cell_dropout,
                                                           seed=CELL_DROPOUT_SEED + cfg.train.seed * 1_000_003 + step)
    weight = loss_weight_map(batch["scan"], batch["mask"], cfg.model.unobserved_weight, run.relief_floor, cfg.model.height_reference)
    valid = batch.get("valid")  # with real scans mixed in: where the target is known
    if cfg.model.fill_relative_loss:
        base = model.generator.base_fill(batch["scan"], batch["mask"])
        per_map = fill_relative_weight(base, batch["target"], batch["mask"], FILL_ERROR_FLOOR, height_loss_power(cfg.model.height_loss), valid,
                                       cfg.model.fill_relative_statistic)
        weight = per_map.expand_as(batch["mask"]) if weight is None else weight * per_map
    if valid is not None:
        weight = valid if weight is None else weight * valid
    model.set_input(model_input(batch["scan"], batch["mask"], cfg.model.in_channels), batch["target"], weight)
    model.optimize_parameters()
    t2 = time.perf_counter()
    run.meter.wait += t1 - t0
    run.meter.busy += t2 - t0
    run.meter.pairs += cfg.train.batch_size


def log(run: TrainingRun, step: int, bar) -> None:
    """Log the last step's losses, the learning rates and the throughput since the last log at
    ``step``; show the losses and the latest validation RMSE on the progress ``bar``; restart
    the throughput counters. The losses are copied to the host without waiting for the device
    (``DeferredScalars``): on a GPU they reach TensorBoard, at their own step, once the copy is
    done, and the bar shows the newest written (on the CPU, this step's)."""
    model, writer, meter = run.model, run.writer, run.meter
    run.scalars.push(step, model.losses)
    losses = run.scalars.latest
    writer.add_scalar("lr/generator", model.optimizer_G.param_groups[0]["lr"], step)
    writer.add_scalar("lr/discriminator", model.optimizer_D.param_groups[0]["lr"], step)
    writer.add_scalar("throughput/pairs_per_s", meter.pairs / max(meter.busy, 1e-9), step)
    writer.add_scalar("throughput/data_wait_share", meter.wait / max(meter.busy, 1e-9), step)
    shown = {key: f"{losses[name]:.3f}" for key, name in (("D", "discriminator"), ("G", "generator_gan"), ("L1", "l1")) if name in losses}
    if math.isfinite(run.rmse):  # no validation score before the first validation
        shown["val"] = f"{run.rmse:.3f}"
    bar.set_postfix(**shown)
    run.meter = Throughput()


def validate(run: TrainingRun, step: int) -> None:
    """Score the validation set (rank 0): keep the RMSE on unobserved cells and the prediction
    in ``run`` and log at ``step`` the RMSE on unobserved, observed and all cells, the
    nearest-neighbour fill's, and with uncertainty its calibration. Other ranks keep nan and
    None. The model predicts in eval mode and is left in the mode it was in."""
    if not run.ranks.main:
        run.rmse, run.prediction = math.nan, None
        return
    writer, target, unobserved = run.writer, run.val["target"], run.unobserved
    prediction, log_variance = predict_in_chunks(run.model, run.val_condition)
    rmse = masked_rmse(prediction, target, unobserved)
    if log_variance is not None:
        fit = calibration(prediction, standard_deviation(log_variance), target, unobserved)
        for key, value in fit.items():
            writer.add_scalar(f"val/uncertainty_{key}_unobserved", value, step)
    writer.add_scalar("val/rmse_unobserved", rmse, step)
    writer.add_scalar("val/rmse_observed", masked_rmse(prediction, target, ~unobserved), step)
    writer.add_scalar("val/rmse_all", masked_rmse(prediction, target, torch.ones_like(unobserved)), step)
    writer.add_scalar("val/nearest_fill_rmse_unobserved", run.nn_rmse, step)
    run.rmse, run.prediction = rmse, prediction
    logger.info("step %d/%d: validation RMSE on unobserved cells %.6f m (best %.6f m); nearest-neighbour fill %.6f m",
             step, run.cfg.train.steps, rmse, min(rmse, run.best), run.nn_rmse)


def keep_best(run: TrainingRun, step: int) -> None:
    """If the latest validation RMSE beats the best so far, it becomes the best and the model is
    saved as ``best.pt``."""
    if run.rmse < run.best:
        run.best = run.rmse
        save(run, BEST, step)


def log_image(run: TrainingRun, step: int) -> None:
    """Log the image grid of the validation set's first maps (``visuals.map_grid``) with the
    latest validation prediction (rank 0), predicting them first if there is none yet."""
    if not run.ranks.main:
        return
    if run.prediction is None:
        run.prediction = predict_in_chunks(run.model, run.val_condition)[0]
    run.writer.add_image("val/scan_mask_prediction_target_error", _grid(run), step)


def save(run: TrainingRun, name: str, step: int) -> None:
    """Checkpoint (rank 0) the model, ``step``, the best score, the RNG states and the config
    as ``checkpoints/name``, atomically."""
    if not run.ranks.main:
        return
    atomic_save(
        {"model": run.model.state_dict(), "step": step, "best": run.best, "rng": rng_state(), "config": OmegaConf.to_container(OmegaConf.structured(run.cfg))},
        run.ckpt_dir / name,
    )
    why = f" (new best validation RMSE {run.best:.6f} m)" if name == BEST else ""
    logger.info("step %d: wrote checkpoint %s%s", step, run.ckpt_dir / name, why)


def finish(run: TrainingRun, callbacks: Sequence, started: float) -> dict:
    """End the run and return its summary (``started``: ``time.perf_counter()`` before the first step).

    A run that had no step left to take scores the loaded model first. Rank 0 then runs the
    ``callbacks``' ``on_finish``, saves ``images/validation.png`` (``visuals.validation_figure``), logs the hyperparameters
    with the final scores, closes the writer and writes ``summary.json``; another rank writes
    only ``summary_rank{rank}.json`` (its first batch seeds). Every rank leaves the process group.
    """
    steps = run.cfg.train.steps
    if run.start >= steps:
        validate(run, steps)
    if not run.ranks.main:
        summary = {"rank": run.ranks.rank, "steps": steps, "first_batch_seeds": _first_batch_seeds(run)}
        write_text(run.run_dir / f"summary_rank{run.ranks.rank}.json", json.dumps(summary))
        close_ranks(run.ranks)
        return summary
    for callback in callbacks:
        callback.on_finish(run.writer, run.model, run.cfg, run.device, steps)
    image_path = run.image_dir / "validation.png"
    val = run.val
    save_figure_png(validation_figure(val["scan"], val["mask"], run.prediction, val["target"], run.cfg.data.map_cell, step=steps), image_path)
    summary = {
        "run_dir": str(run.run_dir),
        "steps": steps,
        "val_rmse_unobserved": run.rmse,
        "best_val_rmse_unobserved": run.best if math.isfinite(run.best) else run.rmse,
        "nearest_fill_rmse_unobserved": run.nn_rmse,
        "wall_s": time.perf_counter() - started,
        "tensorboard": str(run.run_dir / "tensorboard"),
        "checkpoint": str(run.ckpt_dir / LATEST),
        "best_checkpoint": str(run.ckpt_dir / BEST),
        "images": str(image_path),
        "world_size": run.ranks.world,
        "first_batch_seeds": _first_batch_seeds(run),
    }
    run.scalars.flush(wait=True)
    _log_hparams(run)
    run.writer.close()
    write_text(run.run_dir / "summary.json", json.dumps(summary, indent=2))
    logger.info("finished %d steps in %.1f min: validation RMSE on unobserved cells %.6f m (best %.6f m); nearest-neighbour fill %.6f m",
             steps, summary["wall_s"] / 60.0, summary["val_rmse_unobserved"], summary["best_val_rmse_unobserved"], run.nn_rmse)
    logger.info("wrote %s, %s and the TensorBoard log %s", image_path, run.run_dir / "summary.json", summary["tensorboard"])
    close_ranks(run.ranks)
    return summary


def _grid(run: TrainingRun) -> np.ndarray:
    val = run.val
    return map_grid(val["scan"], val["mask"], run.prediction, val["target"])


def _first_batch_seeds(run: TrainingRun) -> list[int]:
    """The seeds of this rank's first (up to 8) batches from ``run.start`` on."""
    tc = run.cfg.train
    return [batch_seed(tc.seed, run.ranks.rank, s) for s in range(run.start, min(run.start + 8, tc.steps))]


def _log_hparams(run: TrainingRun) -> None:
    """The config's scalar values, ``section.key``, and the lidar's name, with the final scores."""
    cfg = run.cfg
    hparams = {f"{section}.{k}": v for section in ("terrain", "data", "model", "train") for k, v in asdict(getattr(cfg, section)).items() if isinstance(v, (int, float, str, bool))}
    hparams["lidar"] = cfg.lidar.name
    metrics = {"hparam/val_rmse_unobserved": run.rmse, "hparam/nearest_fill_rmse_unobserved": run.nn_rmse}
    run.writer.add_hparams(hparams, metrics, run_name="hparams")
