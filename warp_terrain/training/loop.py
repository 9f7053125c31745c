"""The training loop: pulls batches from the stream, steps the model, logs to TensorBoard,
scores the fixed validation set against a nearest-neighbour fill, and checkpoints.

It drives a ``Pix2PixModel`` (nets, losses and visuals are the model's); what it logs beyond
its own scalars and image grids comes in through ``callbacks`` (figures live in ``plots``).
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict
from pathlib import Path
from collections.abc import Sequence

import numpy as np
import torch
from omegaconf import OmegaConf
from torch.utils.tensorboard import SummaryWriter
from tqdm.auto import tqdm

from ..core.atomic import atomic_open, atomic_path
from ..evaluation.baselines import nearest_fill
from ..evaluation.metrics import calibration, masked_rmse
from ..models import build_model
from ..models.fill import loss_weight_map
from ..models.uncertainty import standard_deviation
from ..sim.batch import terrain_size
from ..sim.device import resolve_device
from ..sim.memory import check_batch_fits
from ..core.torchfile import atomic_save, load_checkpoint
from .checkpoint import BEST, LATEST, remove_stale_temporaries, resolve_resume, rng_state, set_rng_state
from .distributed import NullWriter, close_ranks, init_ranks
from ..data.seeds import batch_seed
from ..data.stream import training_batches, validation_set
from ..models.inputs import model_input
from .config import RunConfig

from .visuals import map_grid


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


def train(cfg: RunConfig, run_dir: str | os.PathLike, callbacks: Sequence = ()) -> dict:
    """Train ``cfg.model`` on the stream described by ``cfg``; write everything under ``run_dir``.

    Returns a summary: final and best validation RMSE on unobserved cells, the nearest-neighbour
    fill's RMSE on the same set, wall time and paths. Under ``torchrun`` every rank trains on its
    own stream and rank 0 validates, logs and checkpoints (see ``distributed.py``).
    ``callbacks``: objects whose ``on_finish(writer, model, cfg, device, step)`` runs on rank 0 at the
    end (``plots.callbacks.PaperFigures`` logs the paper's figures; ``python train.py`` passes it).
    """
    tc = cfg.train
    run_dir = Path(run_dir)
    ckpt_dir = run_dir / "checkpoints"
    image_dir = run_dir / "images"
    for d in (ckpt_dir, image_dir):
        d.mkdir(parents=True, exist_ok=True)
    ranks, device = init_ranks(resolve_device(None if tc.device == "auto" else tc.device))
    sim = cfg.sim()
    check_batch_fits(tc.batch_size, terrain_size(sim), sim.lidar.num_rays, sim.data.map_size, device)
    rank = ranks.rank
    threads = tc.threads or (max(1, (os.cpu_count() or 1) - tc.workers) if device == "cpu" else 0)
    if threads:
        torch.set_num_threads(threads)
    torch.manual_seed(tc.seed)
    np.random.seed(tc.seed)

    model = build_model(cfg.model).to(device)
    if ranks.distributed:
        model.distribute([ranks.local_rank] if device.startswith("cuda") else None)
    start, best = 0, math.inf
    if ranks.main:  # a killed run's half-written checkpoint files
        remove_stale_temporaries(ckpt_dir)
    resume_from = resolve_resume(tc.resume, run_dir)
    if resume_from is not None:
        state = load_checkpoint(resume_from)
        model.load_state_dict(state["model"])
        start, best = int(state["step"]), float(state["best"])
        set_rng_state(state["rng"])
    if ranks.main:
        _write_text(run_dir / "run_config.yaml", OmegaConf.to_yaml(OmegaConf.structured(cfg)))

    val = validation_set(sim, tc.val_size if ranks.main else 1, device)
    unobserved = val["mask"] == 0
    nn_rmse = masked_rmse(nearest_fill(val["scan"], val["mask"]), val["target"], unobserved)
    val_condition = model_input(val["scan"], val["mask"], cfg.model.in_channels)

    writer = SummaryWriter(log_dir=str(run_dir / "tensorboard"), purge_step=start if start else None) if ranks.main else NullWriter()
    base_lrs = {id(model.optimizer_G): cfg.model.lr_g, id(model.optimizer_D): cfg.model.lr_d}
    relief_floor = cfg.model.height_scale_min if cfg.model.relief_relative_loss else 0.0

    def validate(step: int) -> tuple[float, torch.Tensor | None]:
        if not ranks.main:
            return math.nan, None
        prediction, log_variance = predict_in_chunks(model, val_condition)
        rmse = masked_rmse(prediction, val["target"], unobserved)
        if log_variance is not None:
            fit = calibration(prediction, standard_deviation(log_variance), val["target"], unobserved)
            for key, value in fit.items():
                writer.add_scalar(f"val/uncertainty_{key}_unobserved", value, step)
        writer.add_scalar("val/rmse_unobserved", rmse, step)
        writer.add_scalar("val/rmse_observed", masked_rmse(prediction, val["target"], ~unobserved), step)
        writer.add_scalar("val/rmse_all", masked_rmse(prediction, val["target"], torch.ones_like(unobserved)), step)
        writer.add_scalar("val/nearest_fill_rmse_unobserved", nn_rmse, step)
        return rmse, prediction

    def save(name: str, step: int) -> None:
        if not ranks.main:
            return
        atomic_save(
            {"model": model.state_dict(), "step": step, "best": best, "rng": rng_state(), "config": OmegaConf.to_container(OmegaConf.structured(cfg))},
            ckpt_dir / name,
        )

    batches = training_batches(sim, tc.batch_size, tc.seed, rank, start, tc.steps, device, tc.workers, tc.prefetch, dataset=tc.dataset)
    bar = tqdm(total=tc.steps, initial=start, disable=not (tc.progress and ranks.main), desc="train", unit="step", dynamic_ncols=True)
    wait = busy = 0.0
    pairs = 0
    t_run = time.perf_counter()
    rmse = math.nan
    last_prediction = None
    model.train()
    for step in range(start, tc.steps):
        t0 = time.perf_counter()
        batch = next(batches)
        if int(batch["step"]) != step:
            raise RuntimeError(f"stream out of order: expected step {step}, got {int(batch['step'])}")
        t1 = time.perf_counter()
        factor = lr_factor(step, tc.steps, tc.lr_decay_from)
        for opt in model.optimizers:
            for g in opt.param_groups:
                g["lr"] = base_lrs[id(opt)] * factor
        batch = {k: v.to(device, non_blocking=True) for k, v in batch.items() if k != "step"}
        weight = loss_weight_map(batch["scan"], batch["mask"], cfg.model.unobserved_weight, relief_floor)
        model.set_input(model_input(batch["scan"], batch["mask"], cfg.model.in_channels), batch["target"], weight)
        model.optimize_parameters()
        t2 = time.perf_counter()
        wait += t1 - t0
        busy += t2 - t0
        pairs += tc.batch_size
        done = step + 1
        if done % tc.log_every == 0 or done == tc.steps:
            losses = model.loss_values()
            for name, value in losses.items():
                writer.add_scalar(f"loss/{name}", value, done)
            writer.add_scalar("lr/generator", model.optimizer_G.param_groups[0]["lr"], done)
            writer.add_scalar("lr/discriminator", model.optimizer_D.param_groups[0]["lr"], done)
            writer.add_scalar("throughput/pairs_per_s", pairs / max(busy, 1e-9), done)
            writer.add_scalar("throughput/data_wait_share", wait / max(busy, 1e-9), done)
            bar.set_postfix(D=f"{losses['discriminator']:.3f}", G=f"{losses['generator_gan']:.3f}", L1=f"{losses['l1']:.3f}", val=f"{rmse:.3f}")
            wait = busy = 0.0
            pairs = 0
        if done % tc.val_every == 0 or done == tc.steps:
            rmse, last_prediction = validate(done)
            model.train()
            if rmse < best:
                best = rmse
                save(BEST, done)
        if ranks.main and (done % tc.image_every == 0 or done == tc.steps):
            if last_prediction is None:
                last_prediction = predict_in_chunks(model, val_condition)[0]
                model.train()
            grid = map_grid(val["scan"], val["mask"], last_prediction, val["target"])
            writer.add_image("val/scan_mask_prediction_target_error", grid, done)
        if done % tc.checkpoint_every == 0 or done == tc.steps:
            save(LATEST, done)
        bar.update(1)
    bar.close()

    if start >= tc.steps:  # nothing left to train: score what was loaded
        rmse, last_prediction = validate(tc.steps)
    if not ranks.main:
        summary = {"rank": rank, "steps": tc.steps, "first_batch_seeds": [batch_seed(tc.seed, rank, s) for s in range(start, min(start + 8, tc.steps))]}
        _write_text(run_dir / f"summary_rank{rank}.json", json.dumps(summary))
        close_ranks(ranks)
        return summary
    for callback in callbacks:
        callback.on_finish(writer, model, cfg, device, tc.steps)
    image_path = image_dir / "validation.png"
    _save_png(map_grid(val["scan"], val["mask"], last_prediction, val["target"]), image_path)
    summary = {
        "run_dir": str(run_dir),
        "steps": tc.steps,
        "val_rmse_unobserved": rmse,
        "best_val_rmse_unobserved": best if math.isfinite(best) else rmse,
        "nearest_fill_rmse_unobserved": nn_rmse,
        "wall_s": time.perf_counter() - t_run,
        "tensorboard": str(run_dir / "tensorboard"),
        "checkpoint": str(ckpt_dir / LATEST),
        "best_checkpoint": str(ckpt_dir / BEST),
        "images": str(image_path),
    }
    hparams = {f"{section}.{k}": v for section in ("terrain", "data", "model", "train") for k, v in asdict(getattr(cfg, section)).items() if isinstance(v, (int, float, str, bool))}
    hparams["lidar"] = cfg.lidar.name
    writer.add_hparams(hparams, {"hparam/val_rmse_unobserved": rmse, "hparam/nearest_fill_rmse_unobserved": nn_rmse}, run_name="hparams")
    writer.close()
    summary["world_size"] = ranks.world
    summary["first_batch_seeds"] = [batch_seed(tc.seed, rank, s) for s in range(start, min(start + 8, tc.steps))]
    _write_text(run_dir / "summary.json", json.dumps(summary, indent=2))
    close_ranks(ranks)
    return summary


def _write_text(path: Path, text: str) -> None:
    with atomic_open(path, "w") as f:
        f.write(text)


def _save_png(grid: np.ndarray, path: Path) -> None:
    import matplotlib.image as mpimg

    with atomic_path(path) as tmp:
        mpimg.imsave(tmp, grid.transpose(1, 2, 0))
