"""Scoring predictors on the fixed test sets (``warp-terrain evaluate``).

A *predictor* is any ``f(scan, mask) -> prediction`` on ``(B, 1, S, S)`` tensors: the classical
fills in :data:`~warp_terrain.evaluation.baselines.BASELINES` are predictors, and
``inference.Predictor`` (``load_predictor``, ``model_predictor``) wraps a model as one. A predictor may also return
``(prediction, sigma)``, a standard deviation per cell: its calibration on unobserved cells is
then scored too (``metrics.calibration``). :func:`evaluate` runs every predictor on every test
set (``testsets``) and returns plain dicts (JSON-ready through ``report.json_ready``), timing
each predictor per map.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Mapping, Sequence

import torch

from ..sim import SimConfig, resolve_device
from ..sim.presets import terrain_preset_names
from .baselines import BASELINES
from .metrics import OBSTACLE_THRESHOLD, calibration, error_metrics, obstacle_iou, pit_recall, range_cells
from .testsets import (
    CHUNK,
    DEFAULT_NOISE,
    DEFAULT_SETTINGS,
    DEFAULT_SIZE,
    TEST_SEED_BASE,
    EvalSet,
    eval_seeds,
    make_eval_set,
    setting_config,
)

__all__ = [
    "PredictorFn",
    "evaluate",
    "run_predictor",
    "score",
]

#: ``(scan, mask) -> heights`` or ``(heights, sigma)``: a ``Predictor`` or a classical fill.
PredictorFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor | tuple[torch.Tensor, torch.Tensor]]
#: ``on_set(ts, predictions)``: called once per scored test set with each method's prediction.
SetCallback = Callable[[EvalSet, dict[str, torch.Tensor]], None]


# ------------------------------------------------------------------------------ one predictor, one set
def _sync(device: str) -> None:
    if str(device).startswith("cuda") and torch.cuda.is_available():
        torch.cuda.synchronize()


def run_predictor(predictor: PredictorFn, ts: EvalSet, device: str) -> tuple[torch.Tensor, torch.Tensor | None, float]:
    """``(prediction, sigma or None, seconds)`` of ``predictor`` on ``ts``, on the CPU; the
    seconds cover the call alone (the device synchronised before and after)."""
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


# ------------------------------------------------------------------------------ arguments
def _setting_names(settings: Iterable[str] | str) -> list[str]:
    """Terrain names from a list or a comma-separated string; ``all``: every preset."""
    if isinstance(settings, str):
        names = [s.strip() for s in settings.split(",") if s.strip()]
    else:
        names = [str(s) for s in settings]
    if names == ["all"]:
        names = terrain_preset_names()
    if not names:
        raise ValueError("settings: give at least one terrain setting")
    return names


def _noise_levels(noise: Iterable[float]) -> list[float]:
    levels = [float(n) for n in noise]
    if not levels:
        raise ValueError("noise: give at least one noise level")
    return levels


def _run_config(first: SimConfig, size: int, threshold: float, device: str) -> dict:
    """The ``config`` block of the results: how every number was made."""
    return {
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
    }


# ------------------------------------------------------------------------------ the loop
def _warm_up(predictors: Mapping[str, PredictorFn], ts: EvalSet, device: str) -> None:
    """Run every predictor once on the first sample (imports, kernel compilation, cuDNN
    autotuning), untimed."""
    one = EvalSet(ts.terrain, ts.noise, ts.sim, ts.seeds, ts.scan[:1], ts.mask[:1], ts.target[:1])
    for f in predictors.values():
        run_predictor(f, one, device)


def _score_set(
    predictors: Mapping[str, PredictorFn], ts: EvalSet, in_range: torch.Tensor, threshold: float, device: str,
    say: Callable[[str], None],
) -> tuple[dict, dict[str, torch.Tensor], dict[str, float]]:
    """``(entry, predictions, seconds)`` of every predictor on one test set."""
    entry = {
        "setting": ts.name,
        "terrain": ts.terrain,
        "noise": ts.noise,
        "samples": len(ts),
        "seeds": ts.seeds,
        "observed_share": float((ts.mask > 0).float().mean()),
        "metrics": {},
    }
    predictions, seconds = {}, {}
    for name, f in predictors.items():
        pred, sigma, dt = run_predictor(f, ts, device)
        m = score(pred, ts, in_range, threshold, sigma)
        m["ms_per_map"] = 1000.0 * dt / len(ts)
        entry["metrics"][name], predictions[name], seconds[name] = m, pred, dt
        say(f"  {name:<12} RMSE unobserved {m['rmse_unobserved']:.4f} m  ({m['ms_per_map']:.1f} ms/map)")
    return entry, predictions, seconds


def evaluate(
    predictors: Mapping[str, PredictorFn] | None = None,
    settings: Iterable[str] | str = DEFAULT_SETTINGS,
    noise: Iterable[float] = DEFAULT_NOISE,
    size: int = DEFAULT_SIZE,
    lidar="hdl32e",
    device=None,
    threshold: float = OBSTACLE_THRESHOLD,
    on_set: SetCallback | None = None,
    progress: Callable[[str], None] | None = None,
    track: Callable[[Sequence, str], Iterable] | None = None,
) -> dict:
    """Score every predictor on every (setting, noise) test set.

    ``predictors``: name -> ``f(scan, mask) -> prediction`` (default: all of ``BASELINES``).
    ``settings``: terrain names (``conf/terrain``) or a comma-separated string (``all``: every
    preset); ``noise``: image noise levels; ``size``: samples per test set; ``lidar``: preset
    name or ``LidarConfig``; ``device``: where the scans are generated and the predictors get
    their inputs; ``on_set(ts, predictions)``: called after each test set is scored, with its
    ``EvalSet`` and each method's ``(N, 1, S, S)`` prediction on the CPU (e.g.
    ``plots.evaluation.figure_writer``); ``progress``: receives one line per step; ``track``:
    ``track(test_sets, "evaluate")`` yields the ``(setting, noise)`` pairs in order while showing
    progress (the CLI passes a tqdm bar on stderr).

    Returns ``{"config": {...}, "methods": [...], "settings": [{"setting", "terrain", "noise",
    "samples", "seeds", "observed_share", "metrics": {method: {metric: value}}}, ...],
    "ms_per_map": {method: ms}}``; metrics are metres (RMSE/MAE), IoU and recall are shares;
    NaN where a metric has no cells (``json_ready`` turns NaN into None).
    """
    predictors = dict(BASELINES) if predictors is None else dict(predictors)
    if not predictors:
        raise ValueError("predictors: nothing to evaluate (give at least one method)")
    settings, noise = _setting_names(settings), _noise_levels(noise)
    eval_seeds(size)  # checks size
    pairs = [(t, n) for t in settings for n in noise]
    first, *_ = [setting_config(t, n, lidar) for t, n in pairs]  # checks every name first
    device = resolve_device(device)
    say = progress or (lambda _line: None)
    in_range = range_cells(first.data.map_size, first.data.map_cell, first.lidar.max_range)

    config = _run_config(first, size, threshold, device)
    results: dict = {"config": config, "methods": list(predictors), "settings": [], "ms_per_map": {}}
    seconds = dict.fromkeys(predictors, 0.0)
    maps = 0
    for terrain, level in pairs if track is None else track(pairs, "evaluate"):
        t0 = time.perf_counter()
        ts = make_eval_set(terrain, level, size, lidar, device)
        say(f"{ts.name}: {len(ts)} samples generated in {time.perf_counter() - t0:.1f} s")
        if maps == 0:
            _warm_up(predictors, ts, device)
        entry, predictions, dt = _score_set(predictors, ts, in_range, threshold, device, say)
        for name in seconds:
            seconds[name] += dt[name]
        maps += len(ts)
        results["settings"].append(entry)
        if on_set is not None:
            on_set(ts, predictions)
    results["ms_per_map"] = {name: 1000.0 * s / maps for name, s in seconds.items()}
    return results
