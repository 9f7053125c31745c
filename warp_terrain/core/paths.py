"""Output paths that stay inside their folder.

Names of output files can come from configuration (a terrain setting's name, a YAML file's
stem); ``output_path`` joins such a name to the folder it belongs in and refuses one that
would land anywhere else (``..``, an absolute path, a symlink pointing out), so a config can
never make a run write outside its run folder.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

_UNSAFE = re.compile(r"[^A-Za-z0-9._+-]+")


def file_name(text: str) -> str:
    """``text`` as a single, portable file-name component (unsafe runs become ``_``)."""
    name = _UNSAFE.sub("_", str(text)).lstrip(".")
    return name or "_"


def output_path(root: str | os.PathLike, *parts: str) -> Path:
    """``root / parts...``, refused with ValueError if it resolves outside ``root``."""
    root = Path(root)
    path = root.joinpath(*parts)
    base = root.resolve()
    resolved = path.resolve()
    if resolved != base and base not in resolved.parents:
        raise ValueError(f"{str(Path(*parts))!r}: output path escapes its folder {str(root)!r}")
    return path
