"""Real scans in the training stream, self-supervised: hide observed cells, learn them.

A real LIDAR sweep has no ground truth off its returns, but its own observed cells are truth for
themselves: hide a share of them, give the net the rest, and score it on the hidden ones. That is
what the real suite measures on its scans (``evaluation.real``, uniform 20 % dropout); training
does the same on *other* recordings (``make real-data`` writes them as ``real_data/train_*.npz``:
other sensors, other places; the suite's scans are never trained on), with shadow-like hidden
blobs as well as scattered cells, and each sweep turned, mirrored and shifted so that one
recording gives many maps.

A mixed batch keeps its synthetic pairs and replaces some by real ones. It carries ``valid``
(B, 1, H, W): 1 where the target is known (every cell of a synthetic pair; the observed cells of a
real one); the training step multiplies its loss weights by it, so a real pair is scored on its
hidden and kept cells only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from scipy import ndimage

from ..core.checks import check_finite, require
from ..sim.projection import project_points

__all__ = ["ScanMixConfig", "ScanPairs", "hide_cells", "load_scan"]


def load_scan(path: Path) -> np.ndarray:
    """``(N, 3)`` float64 points in the sensor frame from a ``make real-data`` scan file."""
    with np.load(path, allow_pickle=False) as data:
        if "points" not in data:
            raise ValueError(f"{str(path)!r}: no 'points' array (not a make real-data scan file)")
        points = np.asarray(data["points"], dtype=np.float64)
    require(points.ndim == 2 and points.shape[1] == 3 and len(points) > 0, str(path), points.shape, "points must be (N, 3), N >= 1")
    return points


@dataclass
class ScanMixConfig:
    """Which real scans are mixed into training, how often, and how their cells are hidden.

    ``files``: levelled scan files (``.npz`` with ``points`` (N, 3) in metres in the sensor frame,
    z up, as ``make real-data`` writes them). ``share``: the expected share of a batch's pairs
    that are real (each pair independently; 0 turns the mix off). Each real pair hides a share of
    its observed cells drawn uniformly from ``[hide_min, hide_max]``: scattered single cells with
    probability ``1 - blob_probability``, else blobs of a smooth random field whose width is
    drawn from ``[1, blob_cells]`` cells (shadow-like holes). The sweep is turned by a uniform
    yaw, mirrored with probability 1/2 and shifted by up to ``shift_m`` metres along each axis.
    """

    files: list[str] = field(default_factory=list)  # scan .npz files
    share: float = 0.0  # expected share of each batch's pairs cut from real scans, [0, 1]
    hide_min: float = 0.1  # least share of a map's observed cells hidden, (0, 1)
    hide_max: float = 0.4  # largest share hidden, [hide_min, 1)
    blob_probability: float = 0.5  # chance that the hidden cells form blobs, not scattered cells
    blob_cells: float = 4.0  # largest blob width (the smoothing's sigma, cells), >= 1
    shift_m: float = 2.0  # largest shift of the sweep along x and along y (m), >= 0

    def enabled(self) -> bool:
        return self.share > 0

    def validate(self, files: bool = True) -> ScanMixConfig:
        for key in ("share", "hide_min", "hide_max", "blob_probability", "blob_cells", "shift_m"):
            check_finite(key, getattr(self, key))
        require(0.0 <= self.share <= 1.0, "share", self.share, "must be in [0, 1]")
        require(0.0 < self.hide_min < 1.0, "hide_min", self.hide_min, "must be in (0, 1)")
        require(self.hide_min <= self.hide_max < 1.0, "hide_max", self.hide_max, f"must be in [hide_min={self.hide_min}, 1)")
        require(0.0 <= self.blob_probability <= 1.0, "blob_probability", self.blob_probability, "must be in [0, 1]")
        require(self.blob_cells >= 1.0, "blob_cells", self.blob_cells, "must be >= 1")
        require(self.shift_m >= 0.0, "shift_m", self.shift_m, "must be >= 0")
        if self.enabled():
            require(len(self.files) > 0, "files", list(self.files), f"share={self.share} mixes in real scans: name them (run `make real-data`)")
        if files:
            for name in self.files:
                require(Path(name).expanduser().is_file(), "files", name, "no such file (run `make real-data`)")
        return self


def hide_cells(observed: np.ndarray, share: float, blob_sigma: float, rng: np.random.Generator) -> np.ndarray:
    """A bool map of ``round(share * observed.sum())`` observed cells to hide: scattered cells
    (``blob_sigma == 0``), or the observed cells where a Gaussian-smoothed white-noise field
    (sigma ``blob_sigma`` cells) is highest, which makes blobs about that wide."""
    cells = np.flatnonzero(observed)
    count = int(round(share * cells.size))
    hidden = np.zeros(observed.size, dtype=bool)
    if count == 0:
        return hidden.reshape(observed.shape)
    if blob_sigma <= 0:
        hidden[rng.choice(cells, size=count, replace=False)] = True
    else:
        field_ = ndimage.gaussian_filter(rng.standard_normal(observed.shape), blob_sigma, mode="wrap").ravel()
        hidden[cells[np.argsort(-field_[cells], kind="stable")[:count]]] = True
    return hidden.reshape(observed.shape)


class ScanPairs:
    """Training pairs cut from real scans (``ScanMixConfig``); the files are read once."""

    def __init__(self, cfg: ScanMixConfig, map_size: int, map_cell: float, fill: float = 0.0):
        self.cfg, self.map_size, self.map_cell, self.fill = cfg.validate(), int(map_size), float(map_cell), float(fill)
        self.scans = [load_scan(Path(name).expanduser()) for name in cfg.files]

    def count(self, batch_size: int, rng: np.random.Generator) -> int:
        """How many of a batch's ``batch_size`` pairs are real (binomial with ``share``)."""
        return int(rng.binomial(batch_size, self.cfg.share)) if self.cfg.enabled() else 0

    def pair(self, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
        """One real pair: ``(scan, mask, target, valid)``, each (S, S) float32. ``target`` is the
        measured map (``fill`` off the sweep, as the scan's unobserved cells), ``valid`` its
        observed cells, ``mask`` those not hidden."""
        cfg = self.cfg
        points = self.scans[rng.integers(len(self.scans))]
        yaw = rng.uniform(0.0, 2.0 * np.pi)
        c, s = np.cos(yaw), np.sin(yaw)
        rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        if rng.random() < 0.5:
            rotation = rotation @ np.diag([1.0, -1.0, 1.0])
        shift = np.r_[rng.uniform(-cfg.shift_m, cfg.shift_m, 2), 0.0]
        height, observed = project_points(points @ rotation.T + shift, self.map_size, self.map_cell, device="cpu")
        height, observed = height[0, 0].numpy(), observed[0, 0].numpy() > 0
        blob = rng.random() < cfg.blob_probability
        hidden = hide_cells(observed, rng.uniform(cfg.hide_min, cfg.hide_max), rng.uniform(1.0, cfg.blob_cells) if blob else 0.0, rng)
        keep = observed & ~hidden
        f32 = np.float32
        return (np.where(keep, height, self.fill).astype(f32), keep.astype(f32), np.where(observed, height, self.fill).astype(f32),
                observed.astype(f32))

    def mix(self, pair: dict[str, torch.Tensor], seed: int) -> dict[str, torch.Tensor]:
        """``pair`` (a synthetic batch: scan, mask, target) with some pairs replaced by real ones
        (drawn from ``seed``, so a batch is reproducible) and ``valid`` added."""
        rng = np.random.default_rng([seed, 0x5CA4])
        count = self.count(pair["scan"].shape[0], rng)
        out = {k: v.clone() for k, v in pair.items()} if count else dict(pair)  # a stream's pair may share memory with the next
        out["valid"] = torch.ones_like(pair["mask"])
        for i in range(count):
            for key, value in zip(("scan", "mask", "target", "valid"), self.pair(rng), strict=True):
                out[key][i, 0] = torch.from_numpy(value).to(out[key].device)
        return out
