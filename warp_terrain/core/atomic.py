"""Atomic file writes: a temporary file in the target's folder, renamed over the target.

A crash or an error at any moment leaves either the old file or the new one, never half of
one. An error leaves no temporary file behind; a killed process (SIGKILL, power cut) may leave
its ``.NAME.XXXX`` temporary file, which is never taken for the target. The result gets the
usual permissions (``0666 & ~umask``; ``mkstemp`` alone would make it ``0600``).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _sync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable (a power cut after it keeps the new file)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return  # not every platform opens folders
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (ending in ``suffix``, default ``path``'s) for a
    writer that wants a file name; on success it replaces ``path``, on failure it is removed.

    A missing or unwritable folder raises ValueError naming it before anything is written.
    """
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise ValueError(f"{str(path)!r}: the folder {str(parent)!r} does not exist")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix if suffix is None else suffix, dir=parent)
    except OSError as err:
        raise ValueError(f"{str(path)!r}: cannot write in {str(parent)!r} ({err.strerror or err})") from None
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
        _sync_folder(parent)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


@contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "wb") -> Iterator:
    """``open`` for writing, atomically: the data is flushed to disk before the rename."""
    with atomic_path(path) as tmp:
        with open(tmp, mode) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
