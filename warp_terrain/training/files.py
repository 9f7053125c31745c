"""The run folder's text files and PNG figure, each written atomically (``core.atomic``)."""

from __future__ import annotations

from pathlib import Path

from ..core.atomic import atomic_open


def write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path``: the old file or the new one, never half of one."""
    with atomic_open(path, "w") as f:
        f.write(text)


def save_figure_png(fig, path: Path, dpi: int = 80) -> None:
    """Save the matplotlib figure ``fig`` (``visuals.validation_figure``) as a PNG at ``path``, atomically."""
    with atomic_open(path, "wb") as f:
        fig.savefig(f, format="png", dpi=dpi)
