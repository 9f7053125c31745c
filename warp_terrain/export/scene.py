"""One generated sample, and a model's reconstruction of it, as a USD stage (``export_sample``)."""

from __future__ import annotations

import os
from pathlib import Path

from ..inference.predictor import Predictor
from ..sim import SimConfig, generate_batch, resolve_device
from ..sim.batch import unaugmented
from .usd import check_usd_path, export_usd


def export_sample(out: str | os.PathLike, sim: SimConfig, seed: int = 0, predictor: Predictor | None = None,
                  with_points: bool = False, device=None) -> Path:
    """Generate sample ``seed`` of ``sim`` (augmentation and randomization off, on a copy) and
    write it with :func:`~warp_terrain.export.usd.export_usd` to ``out`` (``.usda``/``.usdc``):
    its terrain mesh, with ``with_points`` its LIDAR returns, and with ``predictor`` (any
    ``predictor(scan, mask)`` -> heights or ``(heights, sigma)``) its reconstruction and error
    map. ``device``: where the sample is generated (default: CUDA if available, else CPU).
    Returns the written path; a bad ``out`` raises ValueError before any work."""
    out = check_usd_path(out)
    sim = unaugmented(sim)
    device = resolve_device(device)
    batch = generate_batch(1, sim, seed=seed, device=device)
    kwargs = {}
    if predictor is not None:
        predicted = predictor(batch.scan, batch.mask)
        heights = predicted[0] if isinstance(predicted, tuple) else predicted
        kwargs = dict(reconstruction=heights[0, 0], target=batch.target[0, 0], reconstruction_cell=sim.data.map_cell)
    return export_usd(out, batch.heights[0], sim.terrain.cell, points=batch.points[0] if with_points else None,
                      sensor_z=float(batch.sensor_z[0]), **kwargs)
