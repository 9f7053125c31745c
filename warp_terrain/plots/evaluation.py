"""Figures of ``warp-terrain evaluate``: one sample of a test set, every method's fill and error.

:func:`write_figure` draws one PNG per test set; :func:`figure_writer` makes the
``on_set(ts, predictions)`` callback that ``warp_terrain.evaluation.evaluate`` calls after
scoring each set (``warp-terrain evaluate --figures DIR``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np
import torch
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..core.paths import file_name, output_path
from ..evaluation import CHUNK, EvalSet
from ..evaluation.metrics import masked_rmse
from .common import save_figure

__all__ = [
    "figure_writer",
    "write_figure",
]


def write_figure(path, ts: EvalSet, predictions: Mapping[str, torch.Tensor], index: int = 0, dpi: int = 80) -> Path:
    """One PNG for a test set's sample ``index``: top row scan | each method's prediction |
    ground truth (one height colour scale, unobserved scan cells blank); bottom row the
    observation mask | each method's error (prediction - truth, one symmetric scale) with its
    RMSE on unobserved cells. Agg canvas, written atomically."""
    scan = ts.scan[index, 0].numpy()
    mask = ts.mask[index, 0].numpy() > 0
    target = ts.target[index, 0].numpy()
    preds = {m: p[index, 0].numpy() for m, p in predictions.items()}
    cols = len(preds) + 2
    lo, hi = float(target.min()), float(target.max())
    errs = {m: p - target for m, p in preds.items()}
    emax = max([float(np.abs(e).max()) for e in errs.values()] + [1e-3])
    half = 0.5 * ts.sim.data.map_size * ts.sim.data.map_cell
    extent = [-half, half, -half, half]

    fig = Figure(figsize=(2.2 * cols + 1.0, 5.2), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, cols, squeeze=False)

    def show(ax, img, title, **kw):
        # rows of the map are x (forward), columns y: draw x to the right, y up
        im = ax.imshow(np.ma.masked_invalid(img).T, origin="lower", extent=extent, interpolation="nearest", **kw)
        ax.set_title(title, fontsize=8)
        ax.tick_params(labelsize=6)
        return im

    heights = dict(cmap="viridis", vmin=lo, vmax=hi)
    show(axes[0, 0], np.where(mask, scan, np.nan), "scan\n(unobserved blank)", **heights)
    show(axes[1, 0], mask.astype(float), f"observation mask\n{100 * mask.mean():.0f}% observed", cmap="gray", vmin=0, vmax=1)
    im_e = None
    for k, (m, p) in enumerate(preds.items(), start=1):
        im_h = show(axes[0, k], p, f"{m}\nprediction", **heights)
        rmse = masked_rmse(torch.from_numpy(p), torch.from_numpy(target), torch.from_numpy(~mask))
        im_e = show(axes[1, k], errs[m], f"{m} error\nRMSE unobserved {rmse:.3f} m", cmap="RdBu_r", vmin=-emax, vmax=emax)
    im_h = show(axes[0, -1], target, "ground truth\n(cell means)", **heights)
    axes[1, -1].axis("off")
    fig.colorbar(im_h, ax=axes[0, :].tolist(), shrink=0.8, label="z (m, sensor frame)")
    if im_e is not None:
        fig.colorbar(im_e, ax=axes[1, :].tolist(), shrink=0.8, label="error (m)")
    fig.suptitle(f"{_title_short(ts)}: sample {index} (seed {ts.seeds[index // CHUNK]}, #{index % CHUNK})", fontsize=9)
    return save_figure(fig, path, dpi=dpi)


def _title_short(ts: EvalSet) -> str:
    return f"{ts.terrain}, noise {100 * ts.noise:g}%"


def figure_writer(
    folder, sample: int = 0, progress: Callable[[str], None] | None = None
) -> Callable[[EvalSet, Mapping[str, torch.Tensor]], None]:
    """An ``on_set(ts, predictions)`` callback for ``evaluate`` that writes sample ``sample`` of
    each test set as ``<folder>/<terrain>_noise<noise>.png`` (``folder`` is created now) and
    reports each file to ``progress``."""
    if isinstance(sample, bool) or not isinstance(sample, int) or sample < 0:
        raise ValueError(f"sample={sample!r}: must be an integer >= 0")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    say = progress or (lambda _line: None)

    def on_set(ts: EvalSet, predictions: Mapping[str, torch.Tensor]) -> None:
        if sample >= len(ts):
            raise ValueError(f"sample={sample}: the test set {ts.name} has {len(ts)} samples")
        path = output_path(folder, file_name(f"{ts.terrain}_noise{ts.noise:g}.png"))
        write_figure(path, ts, predictions, index=sample)
        say(f"  wrote {path}")

    return on_set
