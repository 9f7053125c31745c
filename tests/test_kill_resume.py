"""Kill and resume: SIGKILL a training run mid-run and mid-checkpoint-write, resume it.

Each run is ``train.py`` in a child process, started through a small wrapper that runs the
real entry (``runpy.run_path("train.py", run_name="__main__")``, so Hydra composes as usual)
and adds two instruments: it appends the step of every batch the loop takes from the stream to
a progress file (unbuffered ``os.write``, so what a killed process did is on disk), and, on
request, it makes the Nth write of ``latest.pt`` write half of its bytes to the temporary file,
flush them to disk and SIGKILL its own process.

After each fault: ``latest.pt`` loads (``weights_only=True``) and is the last checkpoint that
was completely written, at most one checkpoint interval of steps is lost, resume picks the
checkpoint (never a temporary file) and takes the stream from exactly the checkpoint's step
to the end, and the resumed weights, optimiser states included, equal those of an
uninterrupted run of the same length from the same seed.
"""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from conftest import ROOT, TINY_RUN, run_config

from warp_terrain.core.torchfile import load_checkpoint
from warp_terrain.training import train
from warp_terrain.training.checkpoint import LATEST, resolve_resume

TIMEOUT = 120.0  # seconds any one child may take; a step takes well under a second
EVERY = 3  # train.checkpoint_every
TOTAL = 12  # the resumed runs' train.steps (the uninterrupted reference's length)

# tests/test_training.py's tiny run (41x41 maps, narrow nets, a sparse sensor); validation and
# images only at the end of a run, and constant learning rates, so that the killed run (a
# long train.steps), the resumed one and the reference follow the same schedule
TINY = [
    *TINY_RUN,
    "train.device=cpu",  # deterministic kernels (the resumed weights match the reference bit for bit)
    "train.threads=1",  # on a small shared CPU two threads per step can be three times slower
    "train.val_every=100000",
    "train.image_every=100000",
    f"train.checkpoint_every={EVERY}",
    "train.lr_decay_from=1.0",
]
LONG = "train.steps=100000"  # the killed runs: far longer than they will live

WRAPPER = r'''
import io, os, runpy, signal, sys

root, args = sys.argv[1], sys.argv[2:]
progress = os.environ.get("KILL_RESUME_PROGRESS")
die_on_write = int(os.environ.get("KILL_RESUME_DIE_ON_WRITE", "0"))

import torch
import warp_terrain.training.loop as loop

import warp_terrain.plots.callbacks as callbacks

callbacks.PaperFigures.on_finish = lambda *a, **k: None  # the final model's figures: seconds of matplotlib

if progress:
    stream = loop.training_batches

    def recorded(*a, **k):
        fd = os.open(progress, os.O_WRONLY | os.O_CREAT | os.O_APPEND)
        for batch in stream(*a, **k):
            os.write(fd, b"%d\n" % int(batch["step"]))
            yield batch

    loop.training_batches = recorded

if die_on_write:
    save, writes = torch.save, [0]

    def dying_save(obj, f, *a, **k):
        name = os.path.basename(str(getattr(f, "name", "")))
        if name.startswith(".latest.pt."):  # atomic_save's temporary file for latest.pt
            writes[0] += 1
            if writes[0] == die_on_write:
                buf = io.BytesIO()
                save(obj, buf, *a, **k)
                data = buf.getvalue()
                f.write(data[: len(data) // 2])
                f.flush()
                os.fsync(f.fileno())
                os.kill(os.getpid(), signal.SIGKILL)
        return save(obj, f, *a, **k)

    torch.save = dying_save

sys.argv = [os.path.join(root, "train.py"), *args]
runpy.run_path(sys.argv[0], run_name="__main__")
'''

pytestmark = pytest.mark.slow  # processes started, killed and restarted


def _start(tmp_path: Path, run_dir: Path, progress: Path, *overrides, die_on_write: int = 0) -> subprocess.Popen:
    wrapper = tmp_path / "kill_resume_wrapper.py"
    if not wrapper.exists():
        wrapper.write_text(WRAPPER)
    env = dict(os.environ, KILL_RESUME_PROGRESS=str(progress), KILL_RESUME_DIE_ON_WRITE=str(die_on_write))
    args = [sys.executable, str(wrapper), str(ROOT), *TINY, *overrides, f"hydra.run.dir={run_dir}"]
    with open(progress.with_suffix(".log"), "w") as log:
        return subprocess.Popen(args, cwd=tmp_path, env=env, stdout=log, stderr=subprocess.STDOUT)


def _log(progress: Path) -> str:
    path = progress.with_suffix(".log")
    return path.read_text()[-3000:] if path.exists() else ""


def _wait(proc: subprocess.Popen, progress: Path) -> int:
    try:
        return proc.wait(timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        pytest.fail(f"training child still running after {TIMEOUT:.0f} s:\n{_log(progress)}")


def _steps(progress: Path) -> list[int]:
    return [int(line) for line in progress.read_text().split()] if progress.exists() else []


def _temporaries(ckpt_dir: Path) -> list[str]:
    return sorted(p.name for p in ckpt_dir.iterdir() if p.name.startswith(f".{LATEST}."))


def _resume(tmp_path: Path, run_dir: Path, ckpt_step: int, total: int) -> dict:
    """Continue ``run_dir`` to ``total`` steps; check it took the stream from ``ckpt_step`` on."""
    progress = tmp_path / "resumed.steps"
    proc = _start(tmp_path, run_dir, progress, f"train.steps={total}", "train.resume=true")
    assert _wait(proc, progress) == 0, _log(progress)
    # the step counter continued from the checkpoint, not from 0, and the stream with it
    assert _steps(progress) == list(range(ckpt_step, total))
    state = load_checkpoint(run_dir / "checkpoints" / LATEST)
    assert state["step"] == total
    # no temporary file of a killed write is left behind once the run is resumed
    assert _temporaries(run_dir / "checkpoints") == []
    return state


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The checkpoint of an uninterrupted run of ``total`` steps from the same seed."""
    cache = {}

    def run(total: int) -> dict:
        if total not in cache:
            cfg = run_config(*TINY, f"train.steps={total}")
            threads = torch.get_num_threads()
            try:
                summary = train(cfg, tmp_path_factory.mktemp(f"straight{total}"))
            finally:
                torch.set_num_threads(threads)  # train() sets it for the whole process
            cache[total] = load_checkpoint(summary["checkpoint"])
        return cache[total]

    return run


def _assert_same_model(resumed: dict, straight: dict) -> None:
    assert resumed["step"] == straight["step"]
    a, b = resumed["model"], straight["model"]
    for net in ("netG", "netD"):
        assert a[net].keys() == b[net].keys()
        for name, tensor in a[net].items():
            torch.testing.assert_close(tensor, b[net][name], rtol=1e-4, atol=1e-5, msg=f"{net}.{name}")
    for opt in ("optimizer_G", "optimizer_D"):  # Adam's moments and step counts too
        torch.testing.assert_close(a[opt]["state"], b[opt]["state"], rtol=1e-4, atol=1e-5)


def test_sigkill_mid_run_loses_at_most_one_interval_and_resumes_exactly(tmp_path, reference):
    run_dir = tmp_path / "run"
    ckpt_dir = run_dir / "checkpoints"
    latest = ckpt_dir / LATEST
    progress = tmp_path / "killed.steps"
    proc = _start(tmp_path, run_dir, progress, LONG)

    # watch the run; every version of latest.pt that appears must load
    seen, loaded = None, []
    deadline = time.monotonic() + TIMEOUT
    try:
        while True:
            if proc.poll() is not None:
                pytest.fail(f"training child exited ({proc.returncode}) before it was killed:\n{_log(progress)}")
            if time.monotonic() > deadline:
                pytest.fail(f"no checkpoint and step > {EVERY} within {TIMEOUT:.0f} s:\n{_log(progress)}")
            try:
                stat = latest.stat()
            except FileNotFoundError:
                stat = None
            if stat is not None and (stat.st_ino, stat.st_mtime_ns, stat.st_size) != seen:
                seen = (stat.st_ino, stat.st_mtime_ns, stat.st_size)
                loaded.append(load_checkpoint(latest)["step"])
            done = _steps(progress)
            if loaded and done and done[-1] > loaded[-1]:  # past a checkpoint, inside the next interval
                break
            time.sleep(0.005)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=TIMEOUT)
    assert proc.returncode == -signal.SIGKILL

    started = _steps(progress)
    assert started == list(range(len(started)))
    state = load_checkpoint(latest)  # still loads after the kill
    ckpt_step = state["step"]
    assert all(s % EVERY == 0 for s in [*loaded, ckpt_step]) and loaded == sorted(loaded)
    assert loaded[-1] <= ckpt_step <= len(started)
    # at most one interval lost: at most len(started) steps were done when the process died
    assert len(started) - ckpt_step <= EVERY, (len(started), ckpt_step)
    # what is in the folder: latest.pt, and at most the temporary file of an interrupted write,
    # which resume does not take for a checkpoint
    assert {p.name for p in ckpt_dir.iterdir()} - set(_temporaries(ckpt_dir)) == {LATEST}
    assert resolve_resume("true", run_dir) == latest

    total = TOTAL if ckpt_step < TOTAL - 1 else ckpt_step + 2  # a slow machine may have run on
    resumed = _resume(tmp_path, run_dir, ckpt_step, total)
    _assert_same_model(resumed, reference(total))


def test_sigkill_mid_checkpoint_write_keeps_the_previous_checkpoint(tmp_path, reference):
    run_dir = tmp_path / "run"
    ckpt_dir = run_dir / "checkpoints"
    latest = ckpt_dir / LATEST
    progress = tmp_path / "killed.steps"
    # the second write of latest.pt (after step 2 * EVERY) dies halfway through
    proc = _start(tmp_path, run_dir, progress, LONG, die_on_write=2)
    assert _wait(proc, progress) == -signal.SIGKILL, _log(progress)

    # the process died after finishing step 2 * EVERY, inside the checkpoint write
    assert _steps(progress) == list(range(2 * EVERY))
    # the half-written file never replaced latest.pt: the previous checkpoint is intact
    state = load_checkpoint(latest)
    assert state["step"] == EVERY
    # the half-written temporary file is there, is no checkpoint, and is not taken for one
    temporaries = _temporaries(ckpt_dir)
    assert len(temporaries) == 1, temporaries
    with pytest.raises(ValueError, match="cannot be read"):
        load_checkpoint(ckpt_dir / temporaries[0])
    assert 0 < (ckpt_dir / temporaries[0]).stat().st_size < latest.stat().st_size
    assert resolve_resume("true", run_dir) == latest

    resumed = _resume(tmp_path, run_dir, EVERY, TOTAL)
    _assert_same_model(resumed, reference(TOTAL))
