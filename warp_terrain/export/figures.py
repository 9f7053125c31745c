"""Figures of simulated samples: terrain, LIDAR points, scan image, mask and ground truth.

:func:`write_preview` renders one generated sample per terrain setting (the YAML files in
``conf/terrain/``) as one row of five panels, all heights in the sensor frame (metres) on one
colour scale per row, x/y in metres with x to the right and y up:

1. the terrain heightfield, with the elevation map's square outlined and the sensor marked
2. the LIDAR returns seen from above, coloured by height
3. the projected scan image (mean height per cell; unobserved cells blank)
4. the observation mask
5. the ground-truth elevation map

Drawn with matplotlib's Agg canvas on a private ``Figure`` (pyplot's global state is never
touched); PNGs are written atomically (temporary file in the target folder, then ``os.replace``).
"""

from __future__ import annotations

import io
import os
import tempfile
from pathlib import Path

import numpy as np

from ..sim import SimConfig, generate_batch, resolve_device

__all__ = [
    "load_terrain_setting",
    "preview_figure",
    "save_figure",
    "terrain_config_dir",
    "terrain_setting_names",
    "write_preview",
]

PANEL_TITLES = (
    "terrain (map square dashed)",
    "LIDAR returns from above",
    "scan image: mean z per cell",
    "observation mask",
    "ground truth: mean surface z",
)


# ------------------------------------------------------------------------------ settings
def terrain_config_dir() -> Path:
    """The folder of terrain settings: the project's ``conf/terrain``, else ``./conf/terrain``."""
    for candidate in (Path(__file__).resolve().parents[2] / "conf" / "terrain", Path.cwd() / "conf" / "terrain"):
        if candidate.is_dir():
            return candidate
    raise ValueError("cannot find the terrain settings folder conf/terrain (looked beside the package and in the current folder)")


def terrain_setting_names() -> list[str]:
    """Names of the terrain settings in ``conf/terrain/*.yaml``, sorted."""
    return sorted(p.stem for p in terrain_config_dir().glob("*.yaml"))


def load_terrain_setting(name: str, augment: bool = False) -> SimConfig:
    """A validated ``SimConfig`` with the terrain setting ``name`` (or a path to a terrain YAML)
    merged under ``terrain`` into the structured defaults; ``data.augment`` set to ``augment``."""
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    path = Path(name)
    if path.suffix in (".yaml", ".yml"):
        if not path.is_file():
            raise ValueError(f"terrain={name!r}: no such file")
    else:
        names = terrain_setting_names()
        if name not in names:
            raise ValueError(f"terrain={name!r}: unknown terrain setting; choose from {', '.join(names)}, all, or a .yaml path")
        path = terrain_config_dir() / f"{name}.yaml"
    try:
        merged = OmegaConf.merge(
            OmegaConf.structured(SimConfig),
            {"terrain": OmegaConf.load(path), "data": {"augment": bool(augment)}},
        )
        sim = OmegaConf.to_object(merged)
    except (OmegaConfBaseException, OSError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ValueError(f"terrain={name!r}: cannot load {path}: {first}") from None
    except Exception as e:  # YAML syntax errors and the like
        raise ValueError(f"terrain={name!r}: cannot read {path}: {type(e).__name__}") from None
    sim.validate()
    return sim


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
            raise ValueError(f"no terrain settings found in {terrain_config_dir()}")
    return names


# ------------------------------------------------------------------------------ figure
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


def _grid_extent(n: int, cell: float) -> list[float]:
    """imshow extent (left, right, bottom, top) of an n x n grid of cell-centred values."""
    half = 0.5 * n * cell
    return [-half, half, -half, half]


def preview_figure(samples: list[tuple[str, SimConfig]], seed: int = 0, device=None, cmap: str = "viridis"):
    """A matplotlib ``Figure`` with one row of five panels per ``(name, SimConfig)``."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import ListedColormap, Normalize
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    device = resolve_device(device)
    rows = len(samples)
    fig = Figure(figsize=(17.5, 3.3 * rows + 0.6), layout="constrained")
    FigureCanvasAgg(fig)
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
        im = ax.imshow(s["heights"].T, origin="lower", extent=_grid_extent(H, sim.terrain.cell), cmap=cmap, norm=norm, interpolation="nearest")
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
        ax.imshow(scan.T, origin="lower", extent=_grid_extent(S, mc), cmap=cmap, norm=norm, interpolation="nearest")
        ax.set_facecolor("white")

        ax = row[3]
        ax.imshow(s["mask"].T.astype(float), origin="lower", extent=_grid_extent(S, mc), cmap=mask_cmap, vmin=0, vmax=1, interpolation="nearest")
        ax.text(0.02, 0.02, f"observed (blue): {100 * s['mask'].mean():.1f}% of cells", transform=ax.transAxes, fontsize=8,
                bbox=dict(fc="white", ec="none", alpha=0.8, pad=1.5))

        ax = row[4]
        ax.imshow(s["target"].T, origin="lower", extent=_grid_extent(S, mc), cmap=cmap, norm=norm, interpolation="nearest")

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


def save_figure(fig, out, dpi: int = 80, colors: int | None = 256) -> Path:
    """Write ``fig`` as a PNG at ``out`` atomically; the folder must exist.

    ``colors``: quantise to a palette of this many colours (a third of the size of a full-colour
    PNG for these plots, with no visible change); None keeps full colour.
    """
    out = _check_out(out)
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            if colors:
                from PIL import Image

                buf = io.BytesIO()
                fig.savefig(buf, format="png", dpi=dpi)
                buf.seek(0)
                with Image.open(buf) as img:
                    img.convert("RGB").quantize(colors=int(colors), method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(f, format="PNG", optimize=True)
            else:
                fig.savefig(f, format="png", dpi=dpi)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, out)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    return out


def _check_out(out) -> Path:
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise ValueError(f"out={str(out)!r}: the file name must end in .png")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise ValueError(f"out={str(out)!r}: the output folder {str(parent)!r} does not exist")
    if out.is_dir():
        raise ValueError(f"out={str(out)!r}: is a folder, not a file name")
    return out


def write_preview(out, terrain="octave5", seed: int = 0, device=None, dpi: int = 80) -> Path:
    """Generate one sample per terrain setting and write the preview PNG to ``out``.

    ``terrain``: a setting name from ``conf/terrain`` (``octave3``, ``octave5``,
    ``flat_cylinders``, ``negative_obstacles``), a comma-separated list of them, ``"all"``, or a
    path to a terrain YAML. Arguments are checked (output folder, names) before any work.
    """
    out = _check_out(out)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"seed={seed!r}: must be an integer")
    if isinstance(dpi, bool) or not isinstance(dpi, (int, np.integer)) or not 10 <= dpi <= 600:
        raise ValueError(f"dpi={dpi!r}: must be an integer in [10, 600]")
    samples = [(Path(n).stem, load_terrain_setting(n, augment=False)) for n in _resolve_terrains(terrain)]
    device = resolve_device(device)
    fig = preview_figure(samples, seed=int(seed), device=device)
    return save_figure(fig, out, dpi=int(dpi))
