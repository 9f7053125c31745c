"""The run folder's text files and PNG image, each written atomically (``core.atomic``)."""

from __future__ import annotations

from pathlib import Path

import matplotlib.image as mpimg
import numpy as np

from ..core.atomic import atomic_open, atomic_path


def write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path``: the old file or the new one, never half of one."""
    with atomic_open(path, "w") as f:
        f.write(text)


def save_png(grid: np.ndarray, path: Path) -> None:
    """Save a ``(3, H, W)`` float image in [0, 1] (``visuals.map_grid``) as a PNG at ``path``."""
    with atomic_path(path) as tmp:
        mpimg.imsave(tmp, grid.transpose(1, 2, 0))
