"""Checkpoints: written atomically, read with ``torch.load(weights_only=True)``.

A checkpoint is a plain dict of tensors and Python primitives: the model's nets and
optimisers, the step, the RNG states and the best validation score so far. It is written to a
temporary file in the same folder, flushed to disk and renamed over the old one, so a crash at
any moment leaves either the previous checkpoint or the new one, never half of one.
"""

from __future__ import annotations

import os
import random
from pathlib import Path

import numpy as np
import torch

from .config import RESUME_LATEST, RESUME_OFF

LATEST = "latest.pt"
BEST = "best.pt"


def remove_stale_temporaries(folder: str | os.PathLike) -> list[Path]:
    """Delete the temporary files of checkpoint writes that never finished (a SIGKILL, an OOM
    kill or a power cut mid-write leaves ``.latest.pt.XXXX.pt`` behind, as large as a
    checkpoint, one per crash). Call it when no other process writes to ``folder``."""
    folder = Path(folder)
    stale = [p for name in (LATEST, BEST) for p in folder.glob(f".{name}.*") if p.is_file()]
    for p in stale:
        p.unlink(missing_ok=True)
    return stale


def rng_state() -> dict:
    np_state = np.random.get_state()
    state = {
        "torch": torch.get_rng_state(),
        "numpy": [np_state[0], torch.from_numpy(np_state[1].astype(np.int64)), *np_state[2:]],
        "python": _python_state(random.getstate()),
    }
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"])
    kind, keys, *rest = state["numpy"]
    np.random.set_state((kind, keys.numpy().astype(np.uint32), *rest))
    version, internal, gauss = state["python"]
    random.setstate((version, tuple(internal), gauss))
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def _python_state(state):
    version, internal, gauss = state
    return [version, list(internal), gauss]


def resolve_resume(resume: str, run_dir: Path) -> Path | None:
    """The checkpoint to continue from: None for ``false``; the run folder's latest for ``true``;
    else a checkpoint file or a run folder (its ``checkpoints/latest.pt``)."""
    value = str(resume).strip()
    if value.lower() in RESUME_OFF:
        return None
    if value.lower() in RESUME_LATEST:
        path = run_dir / "checkpoints" / LATEST
        if not path.is_file():
            raise ValueError(f"train.resume=true: no checkpoint at {str(path)!r} (set hydra.run.dir to the run folder to continue)")
        return path
    path = Path(value).expanduser()
    if path.is_dir():
        path = path / "checkpoints" / LATEST if (path / "checkpoints").is_dir() else path / LATEST
    if not path.is_file():
        raise ValueError(f"train.resume={value!r}: no checkpoint at {str(path)!r}")
    return path
