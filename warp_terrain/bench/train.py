"""TRAIN: the paper's model (Table 2 generator, ngf 64, and the PatchGAN) -> ``images_per_s`` of
pix2pix optimiser steps on a fixed batch (no data time), the same steps pulling batches from
the training stream (``data_wait_share``), and the channels_last and ``torch.compile`` variants.

The ``torch.compile`` variant runs in a child process (:mod:`.compiled_child`) watched from
here, so that a compile that fails or takes too long is recorded, not fatal.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterable

import torch

from ..data.stream import make_pair, training_batches
from ..models import ModelConfig, build_model
from ..models.inputs import model_input
from ..sim import resolve_device
from ..training.config import RunConfig, TrainConfig
from .harness import SEED, summarize, sync_device, time_calls, torch_threads, workload_result

COMPILE_LIMIT_S = 120.0  # torch.compile gets this long for its first steps, else it is recorded as too slow
STARTUP_LIMIT_S = 120.0  # the compile child's imports, model and data, before its compile limit starts
CHILD_MODULE = f"{__package__}.compiled_child"


# ------------------------------------------------------------------------------- model and data
def _train_model_config(quick: bool) -> ModelConfig:
    """The paper's model: Table 2's generator (ngf 64) and the 70x70 PatchGAN; ``quick``: 8 filters."""
    return ModelConfig(name="paper", ngf=8, ndf=8) if quick else ModelConfig(name="paper")


def fixed_pair(batch: int, device: str) -> dict[str, torch.Tensor]:
    """One training batch of the default stream, generated once (its time excluded)."""
    return make_pair(RunConfig().sim(), batch, SEED & 0x7FFFFFFF, device)


def build_train_model(model_cfg: ModelConfig, device: str, channels_last: bool = False):
    """The pix2pix model, seeded, on ``device``, in training mode (nets channels-last if asked)."""
    torch.manual_seed(SEED)
    model = build_model(model_cfg).to(device)
    if channels_last:
        model.netG.to(memory_format=torch.channels_last)
        model.netD.to(memory_format=torch.channels_last)
    model.train()
    return model


def train_inputs(pair: dict, in_channels: int, device: str, channels_last: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """The network's condition and target of a pair, on ``device`` (channels-last if asked)."""
    pair = {k: v.to(device) for k, v in pair.items() if k != "step"}
    x, y = model_input(pair["scan"], pair["mask"], in_channels), pair["target"]
    if channels_last:
        x, y = x.contiguous(memory_format=torch.channels_last), y.contiguous(memory_format=torch.channels_last)
    return x, y


# ------------------------------------------------------------------------------- variants
def _train_fixed(model_cfg: ModelConfig, batch: int, device: str, repeats: int, channels_last: bool = False) -> dict:
    """Optimiser steps (D then G, as training does) on one fixed batch: no data time."""
    model = build_train_model(model_cfg, device, channels_last)
    x, y = train_inputs(fixed_pair(batch, device), model_cfg.in_channels, device, channels_last)

    def step():
        model.set_input(x, y)
        model.optimize_parameters()

    timing = summarize(time_calls(step, device, repeats))
    return {**timing, "images_per_s": batch / timing["median_s"]}


def _train_stream(model_cfg: ModelConfig, batch: int, device: str, steps: int) -> dict:
    """The same steps pulling their batches from the training stream (``workers=0``: generated
    in this process, as on CUDA): ``data_wait_share`` = time in ``next(batches)`` / step time."""
    model = build_train_model(model_cfg, device)
    batches = training_batches(RunConfig().sim(), batch, SEED, 0, 0, steps + 1, device, 0)

    def step() -> tuple[float, float]:
        sync_device(device)
        t0 = time.perf_counter()
        pair = next(batches)
        t1 = time.perf_counter()
        pair = {k: v.to(device, non_blocking=True) for k, v in pair.items() if k != "step"}
        model.set_input(model_input(pair["scan"], pair["mask"], model_cfg.in_channels), pair["target"])
        model.optimize_parameters()
        sync_device(device)
        return t1 - t0, time.perf_counter() - t0

    step()  # warm-up (kernel loading, first allocations)
    waits, totals = zip(*(step() for _ in range(steps)))
    total = sum(totals)
    return {
        "steps": steps, "workers": 0, "seconds": total, "step_times_s": [float(t) for t in totals],
        "data_wait_s": [float(t) for t in waits], "images_per_s": batch * steps / total,
        "data_wait_share": sum(waits) / total,
    }


# ------------------------------------------------------------------------------- torch.compile child
def _train_compiled(model_cfg: ModelConfig, batch: int, device: str, repeats: int, plain_step_s: float, threads: int,
                    limit_s: float = COMPILE_LIMIT_S) -> dict:
    """``torch.compile`` (inductor) variant, in a child process so that a compile that fails
    or takes longer than ``limit_s`` is recorded, not fatal: after its start-up (imports, model,
    data: up to 120 s more) the child gets ``limit_s`` for compilation and its first two steps,
    then generous time for ``repeats`` timed steps; past a deadline it is killed. Inductor gets
    an empty cache folder, so the compile is cold (what a first run pays) and reproducible."""
    spec = json.dumps({"device": device, "batch": batch, "repeats": repeats, "threads": threads, "model": model_cfg.to_dict()})
    with tempfile.TemporaryDirectory(prefix="warp-terrain-inductor-") as cache:
        t_start = time.perf_counter()
        proc = _spawn_child(spec, cache)
        lines, err_tail = _pump(proc)
        result = _watch_child(proc, lines, err_tail, t_start, batch, repeats, plain_step_s, limit_s)
    return {**result, "inductor_cache": "empty (cold compile)"}


def _spawn_child(spec: str, cache: str) -> subprocess.Popen:
    """``python -m warp_terrain.bench.compiled_child SPEC`` with inductor's cache in ``cache``."""
    env = {**os.environ, "TORCHINDUCTOR_CACHE_DIR": cache}
    return subprocess.Popen([sys.executable, "-m", CHILD_MODULE, spec], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env, start_new_session=True)  # its own group: inductor's compile workers go with it


def _pump(proc: subprocess.Popen) -> tuple[queue.Queue, list[str]]:
    """Daemon threads that move the child's stdout lines onto a queue (``None`` when it ends)
    and keep the last 20 lines of its stderr in a list."""
    lines: queue.Queue = queue.Queue()
    err_tail: list[str] = []

    def pump_stdout():
        for line in proc.stdout:
            lines.put(line)
        lines.put(None)  # end of output: the child exited

    def pump_stderr():
        for line in proc.stderr:
            err_tail.append(line)
            del err_tail[:-20]

    threading.Thread(target=pump_stdout, daemon=True).start()
    threading.Thread(target=pump_stderr, daemon=True).start()
    return lines, err_tail


def _kill_group(proc: subprocess.Popen) -> None:
    """Kill the child's process group (it and inductor's compile workers) and reap it."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    proc.wait()


def _next_event(lines: queue.Queue, deadline: float) -> dict | None:
    """The child's next JSON event (other output skipped); ``None`` when its output ended.
    Raises ``queue.Empty`` past ``deadline``."""
    while True:
        line = lines.get(timeout=max(deadline - time.perf_counter(), 0.0))
        if line is None:
            return None
        try:
            event = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(event, dict):
            return event


def _watch_child(proc: subprocess.Popen, lines: queue.Queue, err_tail: list[str], t_start: float, batch: int,
                 repeats: int, plain_step_s: float, limit_s: float) -> dict:
    """Follow the child's events (ready, compiled, done) against each phase's deadline; the
    variant's result, or why there is none. The child's group is killed in every case."""
    deadline = t_start + STARTUP_LIMIT_S + limit_s  # start-up, until "ready"
    phase_start, phase = t_start, "start-up"
    compiled = None
    while True:
        try:
            event = _next_event(lines, deadline)
        except queue.Empty:
            _kill_group(proc)
            return {"available": False, "limit_s": limit_s,
                    "reason": f"torch.compile: {phase} took more than {deadline - phase_start:.0f} s (killed)"}
        if event is None:  # the child ended without reporting
            _kill_group(proc)
            tail = " | ".join(x.strip() for x in err_tail[-3:] if x.strip())
            return {"available": False, "reason": f"torch.compile failed (exit {proc.returncode}): {tail[-400:]}", "limit_s": limit_s}
        kind = event.pop("event", None)
        if kind == "ready":
            phase_start, phase = time.perf_counter(), "compilation (first two steps)"
            deadline = phase_start + limit_s
        elif kind == "compiled":
            compiled = event
            phase_start, phase = time.perf_counter(), "the timed steps"
            deadline = phase_start + 60.0 + 5.0 * repeats * plain_step_s
        elif kind == "done":
            _kill_group(proc)  # the child is done; also any stragglers of its group (inductor's compile workers)
            first = compiled["first_two_steps_s"]
            return {"available": True, **event, "images_per_s": batch / event["median_s"],
                    "first_two_steps_s": first, "compile_s": max(first - 2.0 * event["median_s"], 0.0),
                    "limit_s": limit_s}


# ------------------------------------------------------------------------------- workload
def _train_threads(device: str) -> int:
    """torch threads as training uses them by default: on the CPU, the cores the default
    generator worker process leaves (``train.threads=0``, ``train.workers=1``)."""
    if not device.startswith("cpu"):
        return torch.get_num_threads()
    return max(1, (os.cpu_count() or 1) - TrainConfig().workers)


def _train_run(model_cfg: ModelConfig, batch: int, device: str, repeats: int, threads: int) -> dict:
    """One batch size with ``threads`` torch threads: plain, channels_last and stream."""
    with torch_threads(threads):
        plain = _train_fixed(model_cfg, batch, device, repeats)
        channels_last = _train_fixed(model_cfg, batch, device, repeats, channels_last=True)
        stream = _train_stream(model_cfg, batch, device, repeats)
    channels_last["over_plain"] = channels_last["images_per_s"] / plain["images_per_s"]
    stream["over_plain"] = stream["images_per_s"] / plain["images_per_s"]
    return {"batch": batch, "threads": threads, "plain": plain, "channels_last": channels_last, "stream": stream}


def _plain_all_threads(model_cfg: ModelConfig, batch: int, device: str, repeats: int, all_threads: int, plain: dict) -> dict:
    """Plain steps again with torch's own thread count."""
    with torch_threads(all_threads):
        other = _train_fixed(model_cfg, batch, device, repeats)
    return {"threads": all_threads, **other, "over_plain": other["images_per_s"] / plain["images_per_s"]}


def _compile_variant(model_cfg: ModelConfig, batch: int, device: str, repeats: int, threads: int, plain: dict,
                     compile: bool, quick: bool) -> dict:
    """The ``torch.compile`` variant, or why it was skipped."""
    if not compile:
        return {"available": False, "reason": "skipped (--quick)" if quick else "skipped"}
    compiled = _train_compiled(model_cfg, batch, device, repeats, plain["median_s"], threads)
    if compiled["available"]:
        compiled["over_plain"] = compiled["images_per_s"] / plain["images_per_s"]
    return compiled


def bench_train(device=None, quick: bool = False, batches: Iterable[int] | None = None, repeats: int | None = None,
                compile: bool | None = None, threads: int | None = None) -> dict:
    """The paper's model (Table 2 generator, ngf 64, and the PatchGAN): images/s of pix2pix
    optimiser steps for batch 1 (the paper's) and 8.

    Per batch size, with ``threads`` torch threads (default: as training sets them, see
    :func:`_train_threads`): ``plain`` (fixed batch, no data time), ``channels_last`` (nets and
    inputs in channels-last memory format), ``stream`` (batches pulled from the training stream
    in this process, ``workers=0``, with the share of step time spent waiting for data). For the
    first batch size also ``plain_all_threads`` (plain with torch's own thread count, if it
    differs) and ``compile`` (``torch.compile`` of both nets in a child process; compile time
    excluded from images/s but reported; a failure or a compile over ``COMPILE_LIMIT_S`` is
    recorded with its reason). ``quick``: 8 filters, batch 1, one step each, no compile and no
    all-threads repeat.
    """
    device = resolve_device(device)
    model_cfg = _train_model_config(quick)
    batches = [int(b) for b in (batches or ((1,) if quick else (1, 8)))]
    if any(b < 1 for b in batches):
        raise ValueError(f"batches={batches!r}: every batch size must be >= 1")
    repeats = repeats or (1 if quick else 3)
    compile = (not quick) if compile is None else bool(compile)
    all_threads = torch.get_num_threads()
    threads = int(threads or _train_threads(device))
    runs = []
    for k, batch in enumerate(batches):
        run = _train_run(model_cfg, batch, device, repeats, threads)
        if k == 0:
            if all_threads != threads and not quick:
                run["plain_all_threads"] = _plain_all_threads(model_cfg, batch, device, repeats, all_threads, run["plain"])
            run["compile"] = _compile_variant(model_cfg, batch, device, repeats, threads, run["plain"], compile, quick)
        runs.append(run)
    params = {"model": model_cfg.name, "ngf": model_cfg.ngf, "ndf": model_cfg.ndf, "norm": model_cfg.norm,
              "gan_mode": model_cfg.gan_mode, "batches": batches, "repeats": repeats, "map_size": 121,
              "torch_threads": threads, "torch_threads_default": all_threads, "compile_limit_s": COMPILE_LIMIT_S, "seed": SEED}
    return workload_result("train", device, params, runs=runs,
                           images_per_s={str(r["batch"]): r["plain"]["images_per_s"] for r in runs},
                           data_wait_share={str(r["batch"]): r["stream"]["data_wait_share"] for r in runs})
