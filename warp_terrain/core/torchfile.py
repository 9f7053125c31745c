"""torch files: saved atomically, read with ``torch.load(weights_only=True)``.

A file is a plain dict of tensors and Python primitives. It is written to a temporary file in
the same folder, flushed to disk and renamed over the old one, so a crash at any moment leaves
either the previous file or the new one, never half of one; reading never unpickles code.
"""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import torch

from .atomic import atomic_open


def atomic_save(obj, path: str | os.PathLike) -> None:
    path = Path(path)
    if not path.parent.is_dir():
        raise ValueError(f"checkpoint folder {str(path.parent)!r} does not exist")
    with atomic_open(path) as f:
        torch.save(obj, f)


def read_error(err: BaseException) -> str:
    """A short reason why ``torch.load(weights_only=True)`` failed: never torch's advice to load
    the file with ``weights_only=False`` (that would run whatever code the file holds)."""
    if isinstance(err, pickle.UnpicklingError) or "weights_only" in str(err):
        return "not a file of plain tensors: it holds objects or code that are never loaded (weights_only=True)"
    first = (str(err).strip().splitlines() or [""])[0][:200]
    return f"{type(err).__name__}: {first}" if first else type(err).__name__


def load_checkpoint(path: str | os.PathLike, map_location="cpu") -> dict:
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"checkpoint {str(path)!r} does not exist")
    try:
        return torch.load(path, map_location=map_location, weights_only=True)
    except Exception as err:  # a truncated or foreign file: say which, not a pickle trace
        raise ValueError(f"checkpoint {str(path)!r} cannot be read ({read_error(err)})") from None
