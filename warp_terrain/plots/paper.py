"""The paper's figure kinds: Fig. 1 (octaves), Fig. 3 (scan noise), Figs. 5-8 (a model's maps).

Figures 1 and 3 need only the simulator; 5-8 need a predictor: an ``inference.Predictor`` or any
``f(scan, mask) -> (B, 1, S, S)`` heights (or ``(heights, sigma)``) on ``(B, 1, S, S)`` tensors.
The figure code knows nothing of the training loop.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import torch

from ..compose import load_terrain_setting
from ..inference.predictor import load_predictor
from ..sim import SimConfig, fractal_heightfield, generate_batch, resolve_device
from .common import check_seed, fixed_sim, grid_extent, new_figure, save_figure, shared_norm

FIGURE_FILES = {
    "fig1": "fig1_octaves.png",
    "fig3": "fig3_scan_noise.png",
    "fig5": "fig5_reconstruction_3d.png",
    "fig6": "fig6_input_prediction_truth.png",
    "fig7": "fig7_obstacles.png",
    "fig8": "fig8_negative_obstacles.png",
}

MODEL_FIGURES = ("fig5", "fig6", "fig7", "fig8")


def octaves_figure(octaves=(1, 3, 5, 7), seed: int = 0, device=None, base: str = "octave5", cmap: str = "terrain"):
    """Fig. 1: heightmaps of the same seed for several octave counts (the ``base`` setting's
    relief, obstacles left out), on one colour scale."""

    seed = check_seed(seed)
    octaves = [int(o) for o in octaves]
    if not octaves or min(octaves) < 1:
        raise ValueError(f"octaves={octaves!r}: give one or more integers >= 1")
    t = load_terrain_setting(base).terrain
    size = 257
    maps = [
        fractal_heightfield(1, size, t.cell, octaves=o, persistence=t.persistence, lacunarity=t.lacunarity,
                            feature_size=t.feature_size, amplitude=t.amplitude, seed=seed, device=device)[0].cpu().numpy()
        for o in octaves
    ]
    norm = shared_norm(*maps)
    fig = new_figure((3.2 * len(maps) + 0.8, 3.6))
    axes = np.atleast_1d(fig.subplots(1, len(maps)))
    for ax, o, h in zip(axes, octaves, maps):
        im = ax.imshow(h.T, origin="lower", extent=grid_extent(size, t.cell), cmap=cmap, norm=norm, interpolation="nearest")
        ax.set_title(f"octaves = {o}", fontsize=11)
        ax.set_xlabel("x (m)", fontsize=9)
        ax.tick_params(labelsize=8)
    axes[0].set_ylabel("y (m)", fontsize=9)
    fig.colorbar(im, ax=list(axes), shrink=0.85, pad=0.01).set_label("height (m)", fontsize=9)
    fig.suptitle(f"Fig. 1: fBm Perlin heightmaps for several octave counts (seed {seed}; first wavelength "
                 f"{t.feature_size:g} m, persistence {t.persistence:g})", fontsize=11)
    return fig


def noise_figure(noise=(0.0, 0.05, 0.10), seed: int = 0, device=None, terrain: str = "octave3", cmap: str = "viridis"):
    """Fig. 3: the projected scan image of one scan without and with the paper's image noise
    (Gaussian, ``noise`` times the sample's height range, on observed cells)."""
    seed = check_seed(seed)
    noise = [float(n) for n in noise]
    base = load_terrain_setting(terrain)
    device = resolve_device(device)
    images = []
    for n in noise:
        b = generate_batch(1, fixed_sim(base, noise=n), seed=seed, device=device)
        mask = b.mask[0, 0].cpu().numpy() > 0.5
        images.append(np.ma.masked_where(~mask, b.scan[0, 0].cpu().numpy()))
    norm = shared_norm(*[i.compressed() for i in images])
    S, mc = base.data.map_size, base.data.map_cell
    fig = new_figure((3.4 * len(images) + 0.8, 3.7))
    axes = np.atleast_1d(fig.subplots(1, len(images)))
    for ax, n, img in zip(axes, noise, images):
        im = ax.imshow(img.T, origin="lower", extent=grid_extent(S, mc), cmap=cmap, norm=norm, interpolation="nearest")
        ax.set_facecolor("white")
        ax.set_title("without noise" if n == 0 else f"{100 * n:g}% noise", fontsize=11)
        ax.set_xlabel("x (m)", fontsize=9)
        ax.tick_params(labelsize=8)
    axes[0].set_ylabel("y (m)", fontsize=9)
    fig.colorbar(im, ax=list(axes), shrink=0.85, pad=0.01).set_label("z in sensor frame (m)", fontsize=9)
    fig.suptitle(f"Fig. 3: ground-projected LIDAR scan image ({terrain}, {base.lidar.name}, seed {seed}; blank: no return)", fontsize=11)
    return fig


def _predict(predictor, sim: SimConfig, count: int, seed: int, device: str) -> dict:
    """Generate ``count`` samples and run ``predictor(scan, mask)`` on them; numpy maps."""

    b = generate_batch(count, sim, seed=seed, device=device)
    with torch.no_grad():
        prediction = predictor(b.scan, b.mask)
    prediction = torch.as_tensor(prediction[0] if isinstance(prediction, tuple) else prediction)
    if tuple(prediction.shape) != tuple(b.target.shape):
        raise ValueError(f"predictor: returned shape {tuple(prediction.shape)}, expected {tuple(b.target.shape)}")
    return {
        "scan": b.scan[:, 0].cpu().numpy(),
        "mask": b.mask[:, 0].cpu().numpy() > 0.5,
        "target": b.target[:, 0].cpu().numpy(),
        "prediction": prediction[:, 0].detach().float().cpu().numpy(),
    }


def _rmse(a, b, where) -> float:
    return float(np.sqrt(np.mean((a[where] - b[where]) ** 2))) if where.any() else float("nan")


def reconstruction_3d_figure(predictor, sim: SimConfig, seed: int = 0, device=None, cmap: str = "terrain"):
    """Fig. 5: the original (ground-truth) and the reconstructed terrain as 3-D surfaces."""
    seed = check_seed(seed)
    device = resolve_device(device)
    sim = fixed_sim(sim)
    s = _predict(predictor, sim, 1, seed, device)
    S, mc = sim.data.map_size, sim.data.map_cell
    c = (np.arange(S) - 0.5 * (S - 1)) * mc
    X, Y = np.meshgrid(c, c, indexing="ij")
    truth, pred = s["target"][0], s["prediction"][0]
    norm = shared_norm(truth, pred)
    fig = new_figure((11.0, 5.0))
    for k, (title, z) in enumerate((("original terrain (ground truth)", truth), ("reconstructed terrain", pred))):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        ax.plot_surface(X, Y, z, cmap=cmap, norm=norm, rcount=S, ccount=S, linewidth=0, antialiased=False)
        pad = 0.05 * (norm.vmax - norm.vmin)
        ax.set_zlim(norm.vmin - pad, norm.vmax + pad)
        ax.set_title(title, fontsize=11)
        ax.set_xlabel("x (m)", fontsize=8)
        ax.set_ylabel("y (m)", fontsize=8)
        ax.set_zlabel("z (m)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.view_init(elev=35, azim=-60)
    rmse = _rmse(pred, truth, ~s["mask"][0])
    fig.suptitle(f"Fig. 5: original and reconstructed terrain ({sim.terrain.name}, noise {100 * sim.data.noise:g}%, seed {seed}; "
                 f"RMSE on unobserved cells {rmse:.3f} m)", fontsize=11)
    return fig


def prediction_figure(predictor, sim: SimConfig, samples: int = 3, seed: int = 0, device=None,
                      title: str = "Fig. 6: GAN prediction on test examples", cmap: str = "viridis"):
    """Figs. 6-8: rows of input (scan image) | prediction | ground truth, one colour scale per row,
    with the RMSE of the prediction on the cells the LIDAR did not see."""
    seed = check_seed(seed)
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1:
        raise ValueError(f"samples={samples!r}: must be an integer >= 1")
    device = resolve_device(device)
    sim = fixed_sim(sim)
    s = _predict(predictor, sim, int(samples), seed, device)
    S, mc = sim.data.map_size, sim.data.map_cell
    ext = grid_extent(S, mc)
    fig = new_figure((11.0, 3.3 * samples + 0.6))
    axes = np.atleast_2d(fig.subplots(samples, 3))
    for r in range(samples):
        mask = s["mask"][r]
        norm = shared_norm(s["target"][r], s["prediction"][r])
        scan = np.ma.masked_where(~mask, s["scan"][r])
        panels = (("input: LIDAR scan image", scan), ("prediction", s["prediction"][r]), ("ground truth", s["target"][r]))
        for c, (name, img) in enumerate(panels):
            ax = axes[r, c]
            im = ax.imshow(img.T, origin="lower", extent=ext, cmap=cmap, norm=norm, interpolation="nearest")
            ax.set_facecolor("white")
            if r == 0:
                ax.set_title(name, fontsize=11)
            ax.tick_params(labelsize=8)
            ax.set_xlabel("x (m)", fontsize=8)
        axes[r, 0].set_ylabel("y (m)", fontsize=8)
        axes[r, 1].text(0.02, 0.02, f"RMSE unobserved {_rmse(s['prediction'][r], s['target'][r], ~mask):.3f} m",
                        transform=axes[r, 1].transAxes, fontsize=8, bbox=dict(fc="white", ec="none", alpha=0.8, pad=1.5))
        fig.colorbar(im, ax=list(axes[r]), shrink=0.9, pad=0.01).set_label("z (m)", fontsize=8)
    fig.suptitle(f"{title} ({sim.terrain.name}, {sim.lidar.name}, noise {100 * sim.data.noise:g}%, seed {seed})", fontsize=11)
    return fig


def _obstacle_sim(base: SimConfig, setting: str) -> SimConfig:
    """``base`` (a model's lidar and maps) with the terrain setting ``setting``, not randomised
    (a randomised world that mixes in DEM windows would need the rasters the setting lacks)."""

    sim = copy.deepcopy(base)
    sim.terrain = load_terrain_setting(setting).terrain
    sim.data.randomize.enabled = False
    sim.validate()
    return sim


def write_figures(out_dir, checkpoint=None, seed: int = 0, device=None, dpi: int = 80, predictor=None) -> dict[str, Path]:
    """Write the paper's figure kinds as PNGs into ``out_dir`` (created if missing); returns
    ``{"fig1": path, ...}``. Figs. 1 and 3 always; Figs. 5-8 (they need a model) with a
    ``checkpoint`` (a model file; ``"pretrained"`` for the shipped model) or a ready ``predictor``
    (``inference.Predictor``, which knows the data it was trained on). Each PNG is written atomically."""
    seed = check_seed(seed)
    if isinstance(dpi, bool) or not isinstance(dpi, (int, np.integer)) or not 10 <= dpi <= 600:
        raise ValueError(f"dpi={dpi!r}: must be an integer in [10, 600]")
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"out={str(out_dir)!r}: is a file, not a folder")
    device = resolve_device(device)
    if predictor is None and checkpoint is not None:
        predictor = load_predictor(None if checkpoint == "pretrained" else checkpoint, device, tta=False)  # fails early on a bad file
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ValueError(f"out={str(out_dir)!r}: cannot create the folder ({err.strerror or err})") from None
    figures = {
        "fig1": lambda: octaves_figure(seed=seed, device=device),
        "fig3": lambda: noise_figure(seed=seed, device=device),
    }
    if predictor is not None:
        p, sim = predictor, predictor.sim or SimConfig()
        figures.update({
            "fig5": lambda: reconstruction_3d_figure(p, sim, seed=seed, device=device),
            "fig6": lambda: prediction_figure(p, sim, seed=seed, device=device),
            "fig7": lambda: prediction_figure(p, _obstacle_sim(sim, "flat_cylinders"), samples=2, seed=seed, device=device,
                                              title="Fig. 7: obstacle prediction on a flat surface"),
            "fig8": lambda: prediction_figure(p, _obstacle_sim(sim, "negative_obstacles"), samples=2, seed=seed, device=device,
                                              title="Fig. 8: negative obstacle prediction"),
        })
    written = {}
    for key, make in figures.items():
        written[key] = save_figure(make(), out_dir / FIGURE_FILES[key], dpi=int(dpi))
    return written
