"""What every figure shares: a private Agg figure, colour scales, extents, checks, PNG writing.

Figures are drawn with matplotlib's Agg canvas on a private ``Figure`` (pyplot's global state
is never touched); PNGs are written atomically (temporary file in the target folder, then
``os.replace``).
"""

from __future__ import annotations

import copy
import io
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from PIL import Image

from ..core.atomic import atomic_open
from ..sim import SimConfig


def new_figure(figsize):

    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def shared_norm(*arrays, pad: float = 0.5):

    lo = min(float(np.min(a)) for a in arrays)
    hi = max(float(np.max(a)) for a in arrays)
    if hi - lo < 1e-3:
        lo, hi = lo - pad, hi + pad
    return Normalize(vmin=lo, vmax=hi)


def grid_extent(n: int, cell: float) -> list[float]:
    """imshow extent (left, right, bottom, top) of an n x n grid of cell-centred values."""
    half = 0.5 * n * cell
    return [-half, half, -half, half]


def check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"seed={seed!r}: must be an integer")
    return int(seed)


def fixed_sim(sim: SimConfig, **data) -> SimConfig:
    """A copy of ``sim`` without augmentation or domain randomisation (and ``data`` overrides),
    so a figure shows the setting itself, in the terrain's orientation."""

    sim = copy.deepcopy(sim)
    sim.data.augment = False
    randomize = getattr(sim.data, "randomize", None)
    if randomize is not None:
        randomize.enabled = False
    for key, value in data.items():
        setattr(sim.data, key, value)
    sim.validate()
    return sim


def check_png_path(out) -> Path:
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise ValueError(f"out={str(out)!r}: the file name must end in .png")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise ValueError(f"out={str(out)!r}: the output folder {str(parent)!r} does not exist")
    if out.is_dir():
        raise ValueError(f"out={str(out)!r}: is a folder, not a file name")
    return out


def save_figure(fig, out, dpi: int = 80, colors: int | None = 256) -> Path:
    """Write ``fig`` as a PNG at ``out`` atomically; the folder must exist.

    ``colors``: quantise to a palette of this many colours (a third of the size of a full-colour
    PNG for these plots, with no visible change); None keeps full colour.
    """
    out = check_png_path(out)
    with atomic_open(out) as f:
        if colors:
            buf = io.BytesIO()
            fig.savefig(buf, format="png", dpi=dpi)
            buf.seek(0)
            with Image.open(buf) as img:
                img.convert("RGB").quantize(colors=int(colors), method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(f, format="PNG", optimize=True)
        else:
            fig.savefig(f, format="png", dpi=dpi)
    return out
