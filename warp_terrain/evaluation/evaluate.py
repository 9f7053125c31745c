"""Scoring fills and models in metres on fixed test sets (``warp-terrain evaluate``).

A *test set* is one data setting, a terrain preset (``sim.presets``) at one image-noise
level, with ``size`` samples from the HDL-32E (by default) at the training defaults' map size
and cell, without augmentation. Its samples come from fixed seeds that neither training nor
validation draws:

- training batch seeds lie in ``[0, 2**30)`` (``data.seeds.batch_seed``), validation uses
  ``2**30 + i`` for its ``i``-th chunk of 16 samples (``data.seeds.validation_seed``);
- test chunk ``i`` (samples ``16 i .. 16 i + 15``) uses seed ``TEST_SEED_BASE + i`` with
  ``TEST_SEED_BASE = 2**31 - 2**24``: the top 2**24 seeds of the 31 bits ``generate_batch``
  keeps. Validation would need more than a billion chunks to reach them.

Sample ``b`` of a chunk depends only on (setting, seed, b), so a quick run's samples are the
first samples of the full set, and every setting with the same terrain sees the same terrains
and scans, only the image noise differs. Settings with obstacles also get each sample's bare
ground (the same seed with every obstacle count set to zero: see ``metrics``).

A *predictor* is any ``f(scan, mask) -> prediction`` on ``(B, 1, S, S)`` tensors: the classical
fills in :data:`~warp_terrain.evaluation.baselines.BASELINES` are predictors, and
``inference.Predictor`` (``load_predictor``, ``model_predictor``) wraps a model as one. A predictor may also return
``(prediction, sigma)``, a standard deviation per cell: its calibration on unobserved cells is
then scored too (``metrics.calibration``). :func:`evaluate` runs every predictor on
every test set and returns plain dicts (JSON-ready); :func:`format_table` and
:func:`format_markdown` render them, :func:`write_figure` draws a sample per setting.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..core.paths import file_name, output_path
from ..data.seeds import TEST_SEED_BASE
from ..sim import SimConfig, generate_batch, lidar_preset, resolve_device
from ..sim.presets import preset_sim, terrain_preset_names
from ..sim.terrain import OBSTACLE_KINDS, ObstacleConfig
from .baselines import BASELINES
from .metrics import OBSTACLE_THRESHOLD, calibration, error_metrics, masked_rmse, obstacle_iou, pit_recall, range_cells

__all__ = [
    "CHUNK",
    "DEFAULT_NOISE",
    "DEFAULT_SETTINGS",
    "DEFAULT_SIZE",
    "QUICK_SIZE",
    "TEST_SEED_BASE",
    "EvalSet",
    "eval_seeds",
    "evaluate",
    "format_markdown",
    "format_table",
    "json_ready",
    "make_eval_set",
    "score",
    "setting_config",
    "write_figure",
]

#: Samples per generated chunk (chunk ``i`` is seed ``TEST_SEED_BASE + i``).
CHUNK = 16
DEFAULT_SETTINGS = ("octave3", "octave5", "flat_cylinders", "negative_obstacles")
DEFAULT_NOISE = (0.0, 0.05, 0.10)
DEFAULT_SIZE = 64
QUICK_SIZE = 4
POSITIVE_KINDS = ("cylinders", "boxes", "rocks")
NEGATIVE_KINDS = ("pits", "ditches")

#: ``(scan, mask) -> heights`` or ``(heights, sigma)``: a ``Predictor`` or a classical fill.
PredictorFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor | tuple[torch.Tensor, torch.Tensor]]


# ------------------------------------------------------------------------------ test sets
def eval_seeds(size: int, chunk: int = CHUNK) -> list[int]:
    """The generator seeds of a test set of ``size`` samples (one per chunk of ``chunk``)."""
    if isinstance(size, bool) or not isinstance(size, int) or size < 1:
        raise ValueError(f"size={size!r}: must be an integer >= 1")
    if size > chunk * 2**24:
        raise ValueError(f"size={size}: at most {chunk * 2**24} samples (2**24 test seeds)")
    return [TEST_SEED_BASE + i for i in range(math.ceil(size / chunk))]


@dataclass
class EvalSet:
    """One data setting's fixed samples, on the CPU: ``(N, 1, S, S)`` tensors."""

    terrain: str
    noise: float
    sim: SimConfig
    seeds: list[int]
    scan: torch.Tensor
    mask: torch.Tensor
    target: torch.Tensor
    ground: torch.Tensor | None = None  # bare ground (obstacles removed), if the setting has obstacles
    positive: bool = False  # has cylinders / boxes / rocks
    negative: bool = False  # has pits / ditches
    extra: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return setting_name(self.terrain, self.noise)

    def __len__(self) -> int:
        return int(self.scan.shape[0])


def setting_name(terrain: str, noise: float) -> str:
    return f"{terrain}/noise{noise:g}"


def bare_config(sim: SimConfig) -> SimConfig:
    """``sim`` with every obstacle count set to zero (the same relief, sensor and maps)."""
    bare = copy.deepcopy(sim)
    for kind in OBSTACLE_KINDS:
        setattr(bare.terrain, kind, ObstacleConfig())
    return bare


def setting_config(terrain: str, noise: float = 0.0, lidar="hdl32e") -> SimConfig:
    """The ``SimConfig`` of a test setting: terrain ``conf/terrain/<terrain>.yaml`` (or a YAML
    path), ``lidar`` (a preset name or a ``LidarConfig``), image noise ``noise``, no augmentation,
    the training defaults' maps (121 x 121 cells of 0.25 m)."""

    if isinstance(noise, bool) or not isinstance(noise, (int, float)) or not 0.0 <= float(noise) <= 1.0:
        raise ValueError(f"noise={noise!r}: must be a number in [0, 1] (a fraction of the height range)")
    sim = preset_sim(terrain, augment=False)
    sim.lidar = lidar_preset(lidar) if isinstance(lidar, str) else copy.deepcopy(lidar)
    sim.data.noise = float(noise)
    sim.validate()
    return sim


def make_eval_set(terrain: str, noise: float = 0.0, size: int = DEFAULT_SIZE, lidar="hdl32e", device=None, chunk: int = CHUNK) -> EvalSet:
    """Generate the fixed test set of one setting (see the module docstring for the seeds)."""
    sim = setting_config(terrain, noise, lidar)
    device = resolve_device(device)
    seeds = eval_seeds(size, chunk)
    positive = any(getattr(sim.terrain, k).count_max > 0 for k in POSITIVE_KINDS)
    negative = any(getattr(sim.terrain, k).count_max > 0 for k in NEGATIVE_KINDS)
    bare = bare_config(sim) if (positive or negative) else None
    parts: dict[str, list[torch.Tensor]] = {"scan": [], "mask": [], "target": [], "ground": []}
    for i, seed in enumerate(seeds):
        n = min(chunk, size - i * chunk)
        b = generate_batch(n, sim, seed=seed, device=device)
        for key in ("scan", "mask", "target"):
            parts[key].append(getattr(b, key).detach().cpu().clone())
        if bare is not None:
            parts["ground"].append(generate_batch(n, bare, seed=seed, device=device).target.detach().cpu().clone())
    return EvalSet(
        terrain=Path(terrain).stem,
        noise=float(noise),
        sim=sim,
        seeds=seeds,
        scan=torch.cat(parts["scan"]),
        mask=torch.cat(parts["mask"]),
        target=torch.cat(parts["target"]),
        ground=torch.cat(parts["ground"]) if bare is not None else None,
        positive=positive,
        negative=negative,
    )


# ------------------------------------------------------------------------------ evaluation
def _sync(device: str) -> None:
    if str(device).startswith("cuda") and torch.cuda.is_available():
        torch.cuda.synchronize()


def _run(predictor: PredictorFn, ts: EvalSet, device: str) -> tuple[torch.Tensor, torch.Tensor | None, float]:
    """``(prediction, sigma or None, seconds)``, on the CPU."""
    scan, mask = ts.scan.to(device), ts.mask.to(device)
    _sync(device)
    start = time.perf_counter()
    out = predictor(scan, mask)
    _sync(device)
    seconds = time.perf_counter() - start
    pred, sigma = out if isinstance(out, tuple) else (out, None)
    for what, t in (("prediction", pred), ("sigma", sigma)):
        if t is not None and tuple(t.shape) != tuple(ts.target.shape):
            raise ValueError(f"predictor returned a {what} of shape {tuple(t.shape)}, expected {tuple(ts.target.shape)}")
    return pred.detach().float().cpu(), None if sigma is None else sigma.detach().float().cpu(), seconds


def score(
    pred: torch.Tensor, ts: EvalSet, in_range: torch.Tensor, threshold: float = OBSTACLE_THRESHOLD, sigma: torch.Tensor | None = None
) -> dict[str, float]:
    """Every metric of one prediction of a test set (with ``sigma``: its calibration on the
    unobserved cells, as ``within_1sigma``, ``within_2sigma``, ``rms_sigma``)."""
    out = error_metrics(pred, ts.target, ts.mask, in_range)
    if sigma is not None:
        out.update(calibration(pred, sigma, ts.target, ts.mask <= 0))
    if ts.ground is not None and ts.positive:
        out["obstacle_iou"] = obstacle_iou(pred, ts.target, ts.ground, threshold)
    if ts.ground is not None and ts.negative:
        out["pit_recall"] = pit_recall(pred, ts.target, ts.ground, threshold)
    return out


def _names(value, allowed: Iterable[str] | None, what: str) -> list[str]:
    names = [s.strip() for s in value.split(",") if s.strip()] if isinstance(value, str) else [str(v) for v in value]
    if allowed is not None:
        allowed = list(allowed)
        unknown = [n for n in names if n not in allowed]
        if unknown:
            raise ValueError(f"{what}={','.join(unknown)}: unknown; choose from {','.join(allowed)}")
    return names


def evaluate(
    predictors: Mapping[str, PredictorFn] | None = None,
    settings: Iterable[str] | str = DEFAULT_SETTINGS,
    noise: Iterable[float] = DEFAULT_NOISE,
    size: int = DEFAULT_SIZE,
    lidar="hdl32e",
    device=None,
    threshold: float = OBSTACLE_THRESHOLD,
    figures: str | Path | None = None,
    figure_sample: int = 0,
    progress: Callable[[str], None] | None = None,
) -> dict:
    """Score every predictor on every (setting, noise) test set.

    ``predictors``: name -> ``f(scan, mask) -> prediction`` (default: all of ``BASELINES``).
    ``settings``: terrain names (``conf/terrain``) or a comma-separated string; ``noise``: image
    noise levels; ``size``: samples per test set; ``lidar``: preset name or ``LidarConfig``;
    ``device``: where the scans are generated and the predictors get their inputs;
    ``figures``: a folder to write one PNG per test set into (sample ``figure_sample``).

    Returns ``{"config": {...}, "methods": [...], "settings": [{"setting", "terrain", "noise",
    "samples", "seeds", "observed_share", "metrics": {method: {metric: value}}}, ...],
    "ms_per_map": {method: ms}}``; metrics are metres (RMSE/MAE), IoU and recall are shares;
    NaN where a metric has no cells (``json_ready`` turns NaN into None).
    """
    predictors = dict(BASELINES) if predictors is None else dict(predictors)
    if not predictors:
        raise ValueError("predictors: nothing to evaluate (give at least one method)")
    settings = _names(settings, None, "settings")
    if settings == ["all"]:

        settings = terrain_preset_names()
    if not settings:
        raise ValueError("settings: give at least one terrain setting")
    noise = [float(n) for n in noise]
    if not noise:
        raise ValueError("noise: give at least one noise level")
    eval_seeds(size)  # checks size
    if not (isinstance(figure_sample, int) and 0 <= figure_sample < size):
        raise ValueError(f"figure_sample={figure_sample!r}: must be in [0, size)")
    if figures is not None:
        figures = Path(figures)
        figures.mkdir(parents=True, exist_ok=True)
    sims = {(t, n): setting_config(t, n, lidar) for t in settings for n in noise}  # check names first
    device = resolve_device(device)
    say = progress or (lambda _line: None)
    first = next(iter(sims.values()))
    in_range = range_cells(first.data.map_size, first.data.map_cell, first.lidar.max_range)

    results: dict = {
        "config": {
            "size": size,
            "lidar": first.lidar.name,
            "max_range_m": first.lidar.max_range,
            "map_size": first.data.map_size,
            "map_cell_m": first.data.map_cell,
            "in_range_radius_m": min(first.lidar.max_range, 0.5 * first.data.map_size * first.data.map_cell),
            "obstacle_threshold_m": threshold,
            "test_seed_base": TEST_SEED_BASE,
            "chunk": CHUNK,
            "augment": False,
            "device": device,
            "torch_threads": torch.get_num_threads(),
        },
        "methods": list(predictors),
        "settings": [],
        "ms_per_map": {},
    }
    seconds = dict.fromkeys(predictors, 0.0)
    maps = 0
    warmed = False
    for terrain in settings:
        for level in noise:
            t0 = time.perf_counter()
            ts = make_eval_set(terrain, level, size, lidar, device)
            say(f"{ts.name}: {len(ts)} samples generated in {time.perf_counter() - t0:.1f} s")
            if not warmed:  # imports, kernel compilation, cuDNN autotuning: not timed
                one = EvalSet(ts.terrain, ts.noise, ts.sim, ts.seeds, ts.scan[:1], ts.mask[:1], ts.target[:1])
                for f in predictors.values():
                    _run(f, one, device)
                warmed = True
            entry = {
                "setting": ts.name,
                "terrain": ts.terrain,
                "noise": ts.noise,
                "samples": len(ts),
                "seeds": ts.seeds,
                "observed_share": float((ts.mask > 0).float().mean()),
                "metrics": {},
            }
            predictions = {}
            for name, f in predictors.items():
                pred, sigma, dt = _run(f, ts, device)
                seconds[name] += dt
                m = score(pred, ts, in_range, threshold, sigma)
                m["ms_per_map"] = 1000.0 * dt / len(ts)
                entry["metrics"][name] = m
                predictions[name] = pred
                say(f"  {name:<12} RMSE unobserved {m['rmse_unobserved']:.4f} m  ({m['ms_per_map']:.1f} ms/map)")
            maps += len(ts)
            results["settings"].append(entry)
            if figures is not None:
                path = output_path(figures, file_name(f"{ts.terrain}_noise{ts.noise:g}.png"))
                write_figure(path, ts, predictions, index=figure_sample)
                say(f"  wrote {path}")
    results["ms_per_map"] = {name: 1000.0 * s / maps for name, s in seconds.items()}
    return results


# ------------------------------------------------------------------------------ rendering
COLUMNS = (
    ("rmse_unobserved", "RMSE unobs (m)"),
    ("mae_unobserved", "MAE unobs (m)"),
    ("rmse_observed", "RMSE obs (m)"),
    ("mae_observed", "MAE obs (m)"),
    ("rmse_in_range", "RMSE in-range (m)"),
    ("mae_in_range", "MAE in-range (m)"),
    ("obstacle_iou", "obstacle IoU"),
    ("pit_recall", "pit recall"),
    ("within_1sigma", "unobs within 1 sigma"),
    ("within_2sigma", "unobs within 2 sigma"),
    ("rms_sigma", "RMS sigma unobs (m)"),
    ("ms_per_map", "ms/map"),
)


def _fmt(key: str, value) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    if key == "ms_per_map":
        return f"{value:.1f}"
    return f"{value:.3f}" if key in ("obstacle_iou", "pit_recall", "within_1sigma", "within_2sigma") else f"{value:.4f}"


def _rows(entry: dict) -> tuple[list[str], list[list[str]]]:
    methods = list(entry["metrics"])
    keys = [k for k, _ in COLUMNS if any(k in entry["metrics"][m] for m in methods)]
    head = ["method"] + [dict(COLUMNS)[k] for k in keys]
    body = [[m] + [_fmt(k, entry["metrics"][m].get(k)) for k in keys] for m in methods]
    return head, body


def _best(entry: dict) -> str:
    scores = {m: v["rmse_unobserved"] for m, v in entry["metrics"].items() if not math.isnan(v["rmse_unobserved"])}
    return min(scores, key=scores.get) if scores else "n/a"


def _title(entry: dict) -> str:
    return (f"{entry['terrain']}, noise {100 * entry['noise']:g}%: {entry['samples']} samples, "
            f"{100 * entry['observed_share']:.1f}% of cells observed")


def format_table(results: dict) -> str:
    """Plain-text tables, one per setting (rows: methods), then the mean time per map."""
    lines = []
    for entry in results["settings"]:
        head, body = _rows(entry)
        widths = [max(len(r[i]) for r in [head] + body) for i in range(len(head))]
        lines.append(_title(entry))
        lines.append("  ".join(h.ljust(w) if i == 0 else h.rjust(w) for i, (h, w) in enumerate(zip(head, widths))))
        for r in body:
            lines.append("  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))))
        lines.append("")
    lines.append("mean time per map: " + ", ".join(f"{m} {ms:.1f} ms" for m, ms in results["ms_per_map"].items()))
    return "\n".join(lines)


def format_markdown(results: dict) -> str:
    """Markdown: a summary (RMSE on unobserved cells, every setting x method), one table per
    setting, the time per map, and how the numbers were made."""
    cfg = results["config"]
    methods = results["methods"]
    out = ["## Evaluation", ""]
    out.append(
        f"{cfg['size']} test samples per setting (seeds from {cfg['test_seed_base']}, never used by training or "
        f"validation), {cfg['lidar']} LIDAR, {cfg['map_size']} x {cfg['map_size']} maps of {cfg['map_cell_m']:g} m, "
        f"no augmentation. RMSE/MAE in metres on unobserved cells, observed cells and the in-range disc "
        f"(radius {cfg['in_range_radius_m']:g} m); obstacle IoU and pit recall against the bare ground at "
        f"{cfg['obstacle_threshold_m']:g} m; time per map on {cfg['device']}."
    )
    out += ["", "### RMSE on unobserved cells (m)", ""]
    out.append("| setting | " + " | ".join(methods) + " | best |")
    out.append("|---|" + "---:|" * len(methods) + "---|")
    for entry in results["settings"]:
        best = _best(entry)
        cells = []
        for m in methods:
            text = _fmt("rmse_unobserved", entry["metrics"][m]["rmse_unobserved"])
            cells.append(f"**{text}**" if m == best else text)
        out.append(f"| {entry['setting']} | " + " | ".join(cells) + f" | {best} |")
    for entry in results["settings"]:
        head, body = _rows(entry)
        out += ["", f"### {_title(entry)}", ""]
        out.append("| " + " | ".join(head) + " |")
        out.append("|---|" + "---:|" * (len(head) - 1))
        out += ["| " + " | ".join(r) + " |" for r in body]
    out += ["", "### Time per map (mean over all settings)", ""]
    out.append("| method | ms/map |")
    out.append("|---|---:|")
    out += [f"| {m} | {ms:.1f} |" for m, ms in results["ms_per_map"].items()]
    return "\n".join(out) + "\n"


def json_ready(obj):
    """``obj`` with NaN/inf floats replaced by None (strict JSON has no NaN)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: json_ready(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(v) for v in obj]
    return obj


# ------------------------------------------------------------------------------ figures
def write_figure(path, ts: EvalSet, predictions: Mapping[str, torch.Tensor], index: int = 0, dpi: int = 80) -> Path:
    """One PNG for a test set's sample ``index``: top row scan | each method's prediction |
    ground truth (one height colour scale, unobserved scan cells blank); bottom row the
    observation mask | each method's error (prediction - truth, one symmetric scale) with its
    RMSE on unobserved cells. Agg canvas, written atomically."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..plots.figures import save_figure

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
