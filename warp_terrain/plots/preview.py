"""Previews of simulated samples: terrain, LIDAR points, scan image, mask and ground truth.

:func:`write_preview` renders one generated sample per terrain setting (the presets in
``sim/presets.py``, or a terrain YAML by path) as one row of five panels, all heights in the
sensor frame (metres) on one colour scale per row, x/y in metres with x to the right and y up:

1. the terrain heightfield, with the elevation map's square outlined and the sensor marked
2. the LIDAR returns seen from above, coloured by height
3. the projected scan image (mean height per cell; unobserved cells blank)
4. the observation mask
5. the ground-truth elevation map
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.colors import ListedColormap, Normalize
from matplotlib.patches import Rectangle

from ..compose import load_terrain_setting, terrain_setting_names
from ..sim import SimConfig, generate_batch, resolve_device
from .common import check_png_path, grid_extent, new_figure, save_figure

PANEL_TITLES = (
    "terrain (map square dashed)",
    "LIDAR returns from above",
    "scan image: mean z per cell",
    "observation mask",
    "ground truth: mean surface z",
)


def _resolve_terrains(terrain) -> list[str]:
    if isinstance(terrain, str):
        names = [t.strip() for t in terrain.split(",") if t.strip()]
    else:
        names = [str(t) for t in terrain]
    if not names:
        raise ValueError(f"terrain={terrain!r}: give a setting name, 'all' or a .yaml path")
    if "all" in names:
        if names != ["all"]:
            raise ValueError(f"terrain={terrain!r}: 'all' cannot be combined with other names")
        names = terrain_setting_names()
        if not names:
            raise ValueError("no terrain settings registered")
    return names


def _sample(sim: SimConfig, seed: int, device: str) -> dict:
    batch = generate_batch(1, sim, seed=seed, device=device)
    sensor_z = float(batch.sensor_z[0].item())
    points = batch.points[0].detach().cpu().numpy()
    return {
        "heights": batch.heights[0].detach().cpu().numpy() - sensor_z,  # sensor frame
        "points": points[np.isfinite(points).all(axis=1)],
        "rays": int(points.shape[0]),
        "scan": batch.scan[0, 0].detach().cpu().numpy(),
        "mask": batch.mask[0, 0].detach().cpu().numpy() > 0.5,
        "target": batch.target[0, 0].detach().cpu().numpy(),
    }


def preview_figure(samples: list[tuple[str, SimConfig]], seed: int = 0, device=None, cmap: str = "viridis"):
    """A matplotlib ``Figure`` with one row of five panels per ``(name, SimConfig)``."""

    device = resolve_device(device)
    rows = len(samples)
    fig = new_figure((17.5, 3.3 * rows + 0.6))
    axes = np.atleast_2d(fig.subplots(rows, 5))
    mask_cmap = ListedColormap(["#e6e6e6", "#31688e"])
    lidar_name = None
    for r, (name, sim) in enumerate(samples):
        s = _sample(sim, seed, device)
        lidar_name = sim.lidar.name
        S, mc = sim.data.map_size, sim.data.map_cell
        H = s["heights"].shape[0]
        half_map = 0.5 * S * mc
        norm = Normalize(vmin=float(s["heights"].min()), vmax=float(s["heights"].max()))
        if norm.vmax - norm.vmin < 1e-3:
            norm = Normalize(vmin=norm.vmin - 0.5, vmax=norm.vmax + 0.5)
        row = axes[r]

        ax = row[0]
        im = ax.imshow(s["heights"].T, origin="lower", extent=grid_extent(H, sim.terrain.cell), cmap=cmap, norm=norm, interpolation="nearest")
        ax.add_patch(Rectangle((-half_map, -half_map), 2 * half_map, 2 * half_map, fill=False, ec="white", lw=1.2, ls="--"))
        ax.plot([0], [0], marker="+", color="red", ms=9, mew=2)

        ax = row[1]
        p = s["points"]
        order = np.argsort(p[:, 2])  # high points drawn last
        ax.scatter(p[order, 0], p[order, 1], c=p[order, 2], s=0.15, lw=0, cmap=cmap, norm=norm, rasterized=True)
        ax.plot([0], [0], marker="+", color="red", ms=9, mew=2)
        ax.set_xlim(-half_map, half_map)
        ax.set_ylim(-half_map, half_map)
        ax.set_aspect("equal")
        ax.set_facecolor("white")
        ax.text(0.02, 0.02, f"{len(p):,} of {s['rays']:,} rays returned", transform=ax.transAxes, fontsize=8,
                bbox=dict(fc="white", ec="none", alpha=0.8, pad=1.5))

        ax = row[2]
        scan = np.ma.masked_where(~s["mask"], s["scan"])
        ax.imshow(scan.T, origin="lower", extent=grid_extent(S, mc), cmap=cmap, norm=norm, interpolation="nearest")
        ax.set_facecolor("white")

        ax = row[3]
        ax.imshow(s["mask"].T.astype(float), origin="lower", extent=grid_extent(S, mc), cmap=mask_cmap, vmin=0, vmax=1, interpolation="nearest")
        ax.text(0.02, 0.02, f"observed (blue): {100 * s['mask'].mean():.1f}% of cells", transform=ax.transAxes, fontsize=8,
                bbox=dict(fc="white", ec="none", alpha=0.8, pad=1.5))

        ax = row[4]
        ax.imshow(s["target"].T, origin="lower", extent=grid_extent(S, mc), cmap=cmap, norm=norm, interpolation="nearest")

        for c, ax in enumerate(row):
            if r == 0:
                ax.set_title(PANEL_TITLES[c], fontsize=11)
            ax.set_xlabel("x (m)", fontsize=9)
            ax.tick_params(labelsize=8)
        row[0].annotate(name, xy=(0, 0.5), xycoords="axes fraction", xytext=(-52, 0), textcoords="offset points",
                        rotation=90, ha="center", va="center", fontsize=12, fontweight="bold")
        row[0].set_ylabel("y (m)", fontsize=9)
        cbar = fig.colorbar(im, ax=list(row), shrink=0.9, aspect=18, pad=0.01)
        cbar.set_label("z in sensor frame (m)", fontsize=9)
        cbar.ax.tick_params(labelsize=8)
    fig.suptitle(
        f"warp-terrain samples (seed {seed}, {lidar_name} mounted {samples[0][1].lidar.mount_height:g} m above the ground, "
        f"{samples[0][1].data.map_size}x{samples[0][1].data.map_size} maps of {samples[0][1].data.map_cell:g} m; "
        "red +: sensor; heights relative to the sensor)",
        fontsize=12,
    )
    return fig


def write_preview(out, terrain="octave5", seed: int = 0, device=None, dpi: int = 80) -> Path:
    """Generate one sample per terrain setting and write the preview PNG to ``out``.

    ``terrain``: a setting name from ``conf/terrain`` (``octave3``, ``octave5``,
    ``flat_cylinders``, ``negative_obstacles``), a comma-separated list of them, ``"all"``, or a
    path to a terrain YAML. Arguments are checked (output folder, names) before any work.
    """
    out = check_png_path(out)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"seed={seed!r}: must be an integer")
    if isinstance(dpi, bool) or not isinstance(dpi, (int, np.integer)) or not 10 <= dpi <= 600:
        raise ValueError(f"dpi={dpi!r}: must be an integer in [10, 600]")
    samples = [(Path(n).stem, load_terrain_setting(n, augment=False)) for n in _resolve_terrains(terrain)]
    device = resolve_device(device)
    fig = preview_figure(samples, seed=int(seed), device=device)
    return save_figure(fig, out, dpi=int(dpi))
