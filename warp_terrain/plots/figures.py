"""Figures of simulated samples: terrain, LIDAR points, scan image, mask and ground truth.

:func:`write_preview` renders one generated sample per terrain setting (the presets in
``sim/presets.py``, or a terrain YAML by path) as one row of five panels, all heights in the sensor frame (metres) on one
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
from pathlib import Path

import numpy as np

from ..compose import load_terrain_setting, terrain_setting_names
from ..core.atomic import atomic_open
from ..inference.predictor import load_predictor
from ..sim import SimConfig, generate_batch, resolve_device

__all__ = [
    "preview_figure",
    "save_figure",
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
    with atomic_open(out) as f:
        if colors:
            from PIL import Image

            buf = io.BytesIO()
            fig.savefig(buf, format="png", dpi=dpi)
            buf.seek(0)
            with Image.open(buf) as img:
                img.convert("RGB").quantize(colors=int(colors), method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(f, format="PNG", optimize=True)
        else:
            fig.savefig(f, format="png", dpi=dpi)
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


# ============================================================================== the paper's figures
# Figures 1 and 3 need only the simulator; 5-8 need a predictor: any callable
# ``f(condition) -> (B, 1, S, S)`` on the condition tensor ``(B, in_channels, S, S)`` (the scan
# image, or scan and observation mask for ``in_channels=2``), e.g. a trained model's ``predict``
# (``load_predictor``). The figure code knows nothing of the training loop.

FIGURE_FILES = {
    "fig1": "fig1_octaves.png",
    "fig3": "fig3_scan_noise.png",
    "fig5": "fig5_reconstruction_3d.png",
    "fig6": "fig6_input_prediction_truth.png",
    "fig7": "fig7_obstacles.png",
    "fig8": "fig8_negative_obstacles.png",
}
MODEL_FIGURES = ("fig5", "fig6", "fig7", "fig8")

__all__ += [
    "FIGURE_FILES",
    "MODEL_FIGURES",
    "noise_figure",
    "octaves_figure",
    "prediction_figure",
    "reconstruction_3d_figure",
    "usd_figure",
    "write_figures",
    "write_usd_figure",
]


def _new_figure(figsize):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _fixed(sim: SimConfig, **data) -> SimConfig:
    """A copy of ``sim`` without augmentation or domain randomisation (and ``data`` overrides),
    so a figure shows the setting itself, in the terrain's orientation."""
    import copy

    sim = copy.deepcopy(sim)
    sim.data.augment = False
    randomize = getattr(sim.data, "randomize", None)
    if randomize is not None:
        randomize.enabled = False
    for key, value in data.items():
        setattr(sim.data, key, value)
    sim.validate()
    return sim


def _norm(*arrays, pad: float = 0.5):
    from matplotlib.colors import Normalize

    lo = min(float(np.min(a)) for a in arrays)
    hi = max(float(np.max(a)) for a in arrays)
    if hi - lo < 1e-3:
        lo, hi = lo - pad, hi + pad
    return Normalize(vmin=lo, vmax=hi)


def _check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"seed={seed!r}: must be an integer")
    return int(seed)


def octaves_figure(octaves=(1, 3, 5, 7), seed: int = 0, device=None, base: str = "octave5", cmap: str = "terrain"):
    """Fig. 1: heightmaps of the same seed for several octave counts (the ``base`` setting's
    relief, obstacles left out), on one colour scale."""
    from ..sim import fractal_heightfield

    seed = _check_seed(seed)
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
    norm = _norm(*maps)
    fig = _new_figure((3.2 * len(maps) + 0.8, 3.6))
    axes = np.atleast_1d(fig.subplots(1, len(maps)))
    for ax, o, h in zip(axes, octaves, maps):
        im = ax.imshow(h.T, origin="lower", extent=_grid_extent(size, t.cell), cmap=cmap, norm=norm, interpolation="nearest")
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
    seed = _check_seed(seed)
    noise = [float(n) for n in noise]
    base = load_terrain_setting(terrain)
    device = resolve_device(device)
    images = []
    for n in noise:
        b = generate_batch(1, _fixed(base, noise=n), seed=seed, device=device)
        mask = b.mask[0, 0].cpu().numpy() > 0.5
        images.append(np.ma.masked_where(~mask, b.scan[0, 0].cpu().numpy()))
    norm = _norm(*[i.compressed() for i in images])
    S, mc = base.data.map_size, base.data.map_cell
    fig = _new_figure((3.4 * len(images) + 0.8, 3.7))
    axes = np.atleast_1d(fig.subplots(1, len(images)))
    for ax, n, img in zip(axes, noise, images):
        im = ax.imshow(img.T, origin="lower", extent=_grid_extent(S, mc), cmap=cmap, norm=norm, interpolation="nearest")
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
    import torch

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
    seed = _check_seed(seed)
    device = resolve_device(device)
    sim = _fixed(sim)
    s = _predict(predictor, sim, 1, seed, device)
    S, mc = sim.data.map_size, sim.data.map_cell
    c = (np.arange(S) - 0.5 * (S - 1)) * mc
    X, Y = np.meshgrid(c, c, indexing="ij")
    truth, pred = s["target"][0], s["prediction"][0]
    norm = _norm(truth, pred)
    fig = _new_figure((11.0, 5.0))
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
    seed = _check_seed(seed)
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1:
        raise ValueError(f"samples={samples!r}: must be an integer >= 1")
    device = resolve_device(device)
    sim = _fixed(sim)
    s = _predict(predictor, sim, int(samples), seed, device)
    S, mc = sim.data.map_size, sim.data.map_cell
    ext = _grid_extent(S, mc)
    fig = _new_figure((11.0, 3.3 * samples + 0.6))
    axes = np.atleast_2d(fig.subplots(samples, 3))
    for r in range(samples):
        mask = s["mask"][r]
        norm = _norm(s["target"][r], s["prediction"][r])
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
    """``base`` (a model's lidar and maps) with the terrain setting ``setting``."""
    import copy

    sim = copy.deepcopy(base)
    sim.terrain = load_terrain_setting(setting).terrain
    sim.validate()
    return sim


def write_figures(out_dir, checkpoint=None, seed: int = 0, device=None, dpi: int = 80, predictor=None) -> dict[str, Path]:
    """Write the paper's figure kinds as PNGs into ``out_dir`` (created if missing); returns
    ``{"fig1": path, ...}``. Figs. 1 and 3 always; Figs. 5-8 (they need a model) with a
    ``checkpoint`` (a model file; ``"pretrained"`` for the shipped model) or a ready ``predictor``
    (``inference.Predictor``, which knows the data it was trained on). Each PNG is written atomically."""
    seed = _check_seed(seed)
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


# ------------------------------------------------------------------------------ a USD stage, drawn
def usd_figure(path, max_points: int = 20000, elev: float = 38.0, azim: float = -62.0):
    """A matplotlib 3-D drawing of a stage written by ``export_usd``: every mesh's triangles as
    they are in the file (world transforms applied, faces coloured by their ``displayColor`` and
    shaded by their normal) and up to ``max_points`` of each point cloud (in red)."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(path))
    if stage is None:
        raise ValueError(f"path={str(path)!r}: cannot open the USD stage")
    cache = UsdGeom.XformCache()
    fig = _new_figure((9.0, 6.0))
    ax = fig.add_subplot(1, 1, 1, projection="3d")
    ax.computed_zorder = False  # points drawn over the surfaces they lie on
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    light = np.array([-0.4, -0.5, 0.77])
    light /= np.linalg.norm(light)
    for prim in stage.Traverse():
        world = np.array(cache.GetLocalToWorldTransform(prim), dtype=np.float64)  # row-vector convention
        if prim.IsA(UsdGeom.Mesh):
            mesh = UsdGeom.Mesh(prim)
            pts = np.asarray(mesh.GetPointsAttr().Get(), dtype=np.float64)
            pts = pts @ world[:3, :3] + world[3, :3]
            counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get())
            if not (counts == 3).all():
                raise ValueError(f"{prim.GetPath()}: only triangle meshes are drawn")
            tris = pts[np.asarray(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)]
            colors = mesh.GetDisplayColorPrimvar().Get()
            rgb = np.full((len(tris), 3), 0.6) if colors is None else np.asarray(colors)[np.asarray(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)].mean(axis=1)
            n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
            shade = 0.45 + 0.55 * np.clip(n @ light, 0.0, 1.0)
            ax.add_collection3d(Poly3DCollection(tris, facecolors=np.clip(rgb * shade[:, None], 0, 1), linewidths=0, antialiased=False))
            lo, hi = np.minimum(lo, pts.min(axis=0)), np.maximum(hi, pts.max(axis=0))
        elif prim.IsA(UsdGeom.Points):
            geom = UsdGeom.Points(prim)
            pts = np.asarray(geom.GetPointsAttr().Get(), dtype=np.float64).reshape(-1, 3)
            if len(pts) == 0:
                continue
            pts = pts @ world[:3, :3] + world[3, :3]
            step = max(1, len(pts) // max(1, int(max_points)))
            ax.scatter(pts[::step, 0], pts[::step, 1], pts[::step, 2], c="red", s=0.4, lw=0, depthshade=False, zorder=10)
    if not np.isfinite(lo).all():
        raise ValueError(f"path={str(path)!r}: the stage holds no mesh")
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    span = hi - lo
    ax.set_box_aspect((span[0], span[1], max(span[2] * 2.0, 0.05 * max(span[0], span[1]))))  # z exaggerated 2x
    ax.view_init(elev=elev, azim=azim)
    from matplotlib.ticker import MaxNLocator

    ax.zaxis.set_major_locator(MaxNLocator(3))
    ax.set_xlabel("x (m)", fontsize=8)
    ax.set_ylabel("y (m)", fontsize=8)
    ax.set_zlabel("z (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.set_title(f"{Path(path).name}: USD meshes as stored, LIDAR points in red (z exaggerated 2x)", fontsize=10)
    return fig


def write_usd_figure(path, out, dpi: int = 80) -> Path:
    """Draw the stage at ``path`` (``usd_figure``) into the PNG ``out``, atomically."""
    out = _check_out(out)
    return save_figure(usd_figure(path), out, dpi=int(dpi))


def save_map_preview(height, mask, map_cell: float, out, title: str = "", dpi: int = 80) -> Path:
    """A PNG of a reconstructed map beside its observation mask (axes in metres)."""
    height, mask = np.asarray(height), np.asarray(mask)
    extent = _grid_extent(height.shape[0], map_cell)
    fig = _new_figure((10, 4.4))
    axes = fig.subplots(1, 2)
    im = axes[0].imshow(height.T, origin="lower", extent=extent, cmap="viridis")
    axes[0].set_title("reconstructed elevation (sensor frame)")
    fig.colorbar(im, ax=axes[0], label="z (m)")
    axes[1].imshow(mask.T, origin="lower", extent=extent, cmap="gray", vmin=0, vmax=1)
    axes[1].set_title(f"observed cells ({100 * mask.mean():.1f} %)")
    for ax in axes:
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    if title:
        fig.suptitle(title)
    return save_figure(fig, out, dpi=dpi)
