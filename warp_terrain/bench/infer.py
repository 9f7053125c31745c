"""INFER: points -> map latency of the shipped ``Reconstructor``, and its network under torch
and ONNX Runtime (CPU provider, optional) with their max abs difference."""

from __future__ import annotations

import copy
import os
import tempfile

import numpy as np
import torch

from ..inference.onnx import export_onnx
from ..inference.reconstructor import Reconstructor
from ..sim import SimConfig, generate_batch, resolve_device
from ..sim.projection import project_points
from .harness import SEED, dist_version, summarize, time_calls, torch_threads, unavailable, workload_result

BATCHES = (1, 4)  # end to end: reconstruct(points) of one scan; project_points + predict_maps of 4


def _onnx_session(generator: torch.nn.Module, in_channels: int, map_size: int, threads_list: list[int]) -> tuple[dict, dict]:
    """Export ``generator`` to a temporary ONNX file and open one ONNX Runtime CPU session per
    thread count; ``({threads: session}, info)`` or ``({}, why not)``."""
    try:
        import onnxruntime as ort
    except (ImportError, OSError) as err:
        return {}, unavailable("onnxruntime", err)
    try:
        sessions = {}
        with tempfile.TemporaryDirectory() as tmp:
            path = export_onnx(copy.deepcopy(generator).cpu(), os.path.join(tmp, "generator.onnx"), in_channels, map_size)
            for n in threads_list:
                options = ort.SessionOptions()
                options.intra_op_num_threads = int(n)
                options.inter_op_num_threads = 1
                sessions[n] = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    except Exception as err:  # noqa: BLE001  (an exporter or runtime problem is a finding, not a crash)
        return {}, {"available": False, "reason": f"export or load failed ({type(err).__name__}: {' '.join(str(err).split())[:300]})"}
    return sessions, {"available": True, "version": dist_version("onnxruntime"), "provider": "CPUExecutionProvider"}


def _end_to_end(rec: Reconstructor, cloud: np.ndarray, scans: torch.Tensor, batch: int, size: int, cell: float,
                device: str, repeats: int) -> dict:
    """Points -> maps of ``batch`` scans: ``reconstruct`` of one cloud, or projection + ``predict_maps``."""
    if batch == 1:
        fn = lambda: rec.reconstruct(cloud, size, cell)  # noqa: E731
    else:
        def fn(points=scans[:batch]):
            scan, mask = project_points(points, map_size=size, map_cell=cell, device=device)
            return rec.predict_maps(scan, mask).cpu()
    timing = summarize(time_calls(fn, device, repeats))
    return {**timing, "median_ms": timing["median_s"] * 1e3, "maps_per_s": batch / timing["median_s"]}


def _single_map(device: str, cloud: np.ndarray, size: int, cell: float, repeats: int) -> dict:
    """``reconstruct`` of one cloud without the 8-orientation average (the issue's "one map from
    a point cloud"): the shipped file as it is (its self-check on) and with the check off."""
    out = {}
    for name, check in (("self_check", None), ("no_check", False)):
        rec = Reconstructor.load(device=device, tta=False, self_check=check)
        timing = summarize(time_calls(lambda rec=rec: rec.reconstruct(cloud, size, cell), device, repeats))
        out[name] = {**timing, "median_ms": timing["median_s"] * 1e3, "checks": rec.self_check, "reach": rec.check_reach}
    return out


def _network_torch(rec: Reconstructor, x: torch.Tensor, device: str, repeats: int) -> dict:
    """The generator alone on conditions ``x``, without grad."""
    def run():
        with torch.no_grad():
            rec.generator(x)

    timing = summarize(time_calls(run, device, repeats))
    return {**timing, "median_ms": timing["median_s"] * 1e3}


def _network_onnx(rec: Reconstructor, session, condition: torch.Tensor, repeats: int, torch_entry: dict) -> tuple[dict, float]:
    """The exported generator in ONNX Runtime on ``condition``: its timing (with the speed-up
    over ``torch_entry``) and its max abs difference from torch's height channel."""
    x = condition.float().cpu().numpy()
    out = {}

    def run():
        out["onnx"] = session.run(["height"], {"condition": x})[0]

    timing = summarize(time_calls(run, "cpu", repeats))
    with torch.no_grad():
        expected = rec.generator(condition)[:, :1].float().cpu().numpy()  # the height channel
    entry = {**timing, "median_ms": timing["median_s"] * 1e3, "speedup_over_torch": torch_entry["median_s"] / timing["median_s"]}
    return entry, float(np.abs(expected - out["onnx"]).max())


def bench_infer(device=None, quick: bool = False, repeats: int | None = None) -> dict:
    """Points -> map latency of the shipped ``Reconstructor`` on HDL-32E scans, and its network
    under torch and ONNX Runtime (CPU provider) with their max abs difference.

    ``end_to_end``: batch 1 is ``reconstruct(points)`` on one scan (its returns only: the NaN
    rows of no-return rays dropped before the clock); batch 4 is ``project_points`` of 4 scans
    at once plus one ``predict_maps`` call (both with the Reconstructor's default test-time
    augmentation: 8 network passes per map). ``single_map``: ``reconstruct`` of that scan
    without the orientation average, with the shipped self-check and without it. ``network``: the generator alone on the conditions
    of those scans, torch (no grad) and ONNX Runtime (exported with ``export_onnx``). Each run
    once with torch's thread count (ONNX Runtime's intra-op threads the same) and, if that is
    more than one, once with one thread (``quick``: one thread only).
    """
    device = resolve_device(device)
    repeats = repeats or (2 if quick else 10)
    rec = Reconstructor.load(device=device)
    sim = SimConfig()
    sim.validate()
    scans = generate_batch(max(BATCHES), sim, seed=SEED, device=device).points
    cloud = scans[0].cpu().numpy()
    cloud = cloud[np.isfinite(cloud).all(axis=1)]
    size, cell = sim.data.map_size, sim.data.map_cell
    scan, mask = project_points(scans, map_size=size, map_cell=cell, device=device)
    condition = rec.condition(scan, mask)
    # --quick: one thread only (torch's OpenMP threads slow down many times over when another
    # process holds a core, which would make the smoke test slow and erratic on shared machines)
    threads_list = [1] if quick else list(dict.fromkeys([torch.get_num_threads(), 1]))
    sessions, onnx = _onnx_session(rec.generator, rec.model_config.in_channels, size, threads_list)
    runs = []
    for threads in threads_list:
        end_to_end, network = {}, {}
        with torch_threads(threads):
            for batch in BATCHES:
                end_to_end[str(batch)] = _end_to_end(rec, cloud, scans, batch, size, cell, device, repeats)
                network[str(batch)] = {"torch": _network_torch(rec, condition[:batch], device, repeats)}
            single = _single_map(device, cloud, size, cell, repeats)
        if threads in sessions:
            for batch in BATCHES:
                entry = network[str(batch)]
                onnx_entry, diff = _network_onnx(rec, sessions[threads], condition[:batch], repeats, entry["torch"])
                entry["onnxruntime"], entry["max_abs_diff_m"] = onnx_entry, diff
        runs.append({"threads": threads, "end_to_end": end_to_end, "single_map": single, "network": network})
    params = {"model": rec.model_config.name, "ngf": rec.model_config.ngf, "in_channels": rec.model_config.in_channels,
              "residual": rec.model_config.residual, "tta": rec.tta, "lidar": sim.lidar.name, "points_in_cloud": int(cloud.shape[0]),
              "rays_per_scan": sim.lidar.num_rays, "map_size": size, "map_cell_m": cell, "batches": list(BATCHES),
              "threads": threads_list, "seed": SEED}
    return workload_result("infer", device, params, runs=runs, onnxruntime=onnx,
                           latency_ms={str(r["threads"]): {k: v["median_ms"] for k, v in r["end_to_end"].items()} for r in runs})
