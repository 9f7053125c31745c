"""Checks outside the training distribution: bigger relief, a higher mount, a finer sensor,
and real terrain shapes.

The real terrain is the DEM that ships inside matplotlib (``jacksboro_fault_dem.npz``, a
344 x 403 grid of elevations in metres at about 3 arc-seconds, ~90 m, from the USGS, used in
matplotlib's hillshading example). Patches are scaled down uniformly, horizontally and
vertically by the same factor, so slopes stay those of the real landscape: one DEM pixel becomes
``dem_pixel`` metres (default 1 m), and heights shrink by ``dem_pixel / 90``. Patches are read
with bilinear interpolation onto the simulator's terrain grid, so ridges and valleys are real
shapes no fBm produced. Everything else (the scan, the maps, the metrics) is as in ``scoring.evaluate``.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Mapping

import matplotlib.cbook as cbook
import numpy as np
from scipy import ndimage

from ..sim.batch import generate_batch, terrain_size
from .metrics import range_cells
from .scoring import run_predictor, score
from .testsets import TEST_SEED_BASE, EvalSet, setting_config

DEM_PIXEL_M = 90.0  # approximate ground spacing of the matplotlib sample DEM


def dem_heightfields(count: int, size: int, cell: float, seed: int = 0, dem_pixel: float = 1.0) -> np.ndarray:
    """``(count, size, size)`` float32 terrains cut from the sample DEM, slopes preserved."""
    elevation = np.asarray(cbook.get_sample_data("jacksboro_fault_dem.npz")["elevation"], dtype=np.float64)
    scaled = elevation * (dem_pixel / DEM_PIXEL_M)  # metres, slopes preserved
    span = (size - 1) * cell / dem_pixel  # patch side in DEM pixels
    rng = np.random.default_rng(seed)
    out = np.empty((count, size, size), np.float32)
    steps = np.arange(size) * (cell / dem_pixel)
    for k in range(count):
        i0 = rng.uniform(0, elevation.shape[0] - 1 - span)
        j0 = rng.uniform(0, elevation.shape[1] - 1 - span)
        ii, jj = np.meshgrid(i0 + steps, j0 + steps, indexing="ij")
        patch = ndimage.map_coordinates(scaled, [ii, jj], order=1)
        out[k] = patch - patch[size // 2, size // 2]
    return out


def _fixed_set(name: str, sim, size: int, device: str, heights=None, seed: int = TEST_SEED_BASE + 4096) -> EvalSet:
    b = generate_batch(size, sim, seed=seed, device=device, heights=heights)
    return EvalSet(name, sim.data.noise, sim, [seed], b.scan.cpu().clone(), b.mask.cpu().clone(), b.target.cpu().clone())


def synthetic_edge_sets(size: int = 32, device: str = "cpu") -> list[EvalSet]:
    """The simulator just outside the shipped model's training ranges (fixed seeds, no augmentation)."""
    sim_relief = setting_config("octave5")
    sim_relief.terrain.amplitude = 6.0  # training drew up to 4 m
    sim_long = setting_config("octave3")
    sim_long.terrain.feature_size = 80.0  # training drew up to 40 m
    sim_long.terrain.amplitude = 5.0
    sim_mount = setting_config("octave5")
    sim_mount.lidar.mount_height = 3.2  # the first two cycles drew 1.2-2.5 m, the third (stop 45) 1.2-3.5 m
    sim_fine = setting_config("octave5", lidar="vlp16")
    sim_fine.lidar.azimuth_step_deg = 0.1  # training coarsened every sensor to >= 0.4 deg
    return [_fixed_set("relief 6 m (octave5)", sim_relief, size, device), _fixed_set("features 80 m, relief 5 m", sim_long, size, device),
            _fixed_set("mount 3.2 m", sim_mount, size, device), _fixed_set("VLP-16 at 0.1 deg", sim_fine, size, device)]


def robustness_sets(size: int = 32, device: str = "cpu") -> list[EvalSet]:
    """The synthetic edges and matplotlib's sample DEM, rescaled with slopes kept."""
    sets = synthetic_edge_sets(size, device)
    for noise in (0.0, 0.05):
        sim = copy.deepcopy(setting_config("octave5", noise))
        dem = dem_heightfields(size, terrain_size(sim), sim.terrain.cell, seed=1)
        sets.append(_fixed_set(f"real DEM (matplotlib jacksboro), noise {noise:g}", sim, size, device, heights=dem))
    return sets


def evaluate_robustness(predictors: Mapping[str, Callable], size: int = 32, device: str = "cpu", progress=None, track=None) -> dict:
    """RMSE/MAE etc. of every predictor on every robustness set. ``progress`` receives one line
    per score; ``track(sets, "robustness")``, if given, yields the sets while showing progress."""
    say = progress or (lambda _line: None)
    results = {"size": size, "methods": list(predictors), "settings": []}
    sets = robustness_sets(size, device)
    for ts in sets if track is None else track(sets, "robustness"):
        in_range = range_cells(ts.sim.data.map_size, ts.sim.data.map_cell, ts.sim.lidar.max_range)
        entry = {"setting": ts.terrain, "observed_share": float((ts.mask > 0).float().mean()), "metrics": {}}
        for name, f in predictors.items():
            t0 = time.perf_counter()
            pred, sigma, _ = run_predictor(f, ts, device)
            entry["metrics"][name] = score(pred, ts, in_range, sigma=sigma)
            say(f"{ts.terrain:<40} {name:<12} RMSE unobserved {entry['metrics'][name]['rmse_unobserved']:.4f} m ({time.perf_counter() - t0:.1f} s)")
        results["settings"].append(entry)
    return results


def robustness_markdown(results: dict) -> str:
    methods = results["methods"]
    lines = ["| setting | observed | " + " | ".join(methods) + " |", "|---|---:|" + "---:|" * len(methods)]
    for e in results["settings"]:
        values = [e["metrics"][m]["rmse_unobserved"] for m in methods]
        best = min(range(len(values)), key=lambda i: values[i])
        cells = [f"**{v:.4f}**" if i == best else f"{v:.4f}" for i, v in enumerate(values)]
        lines.append(f"| {e['setting']} | {100 * e['observed_share']:.0f} % | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
