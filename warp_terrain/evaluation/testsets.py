"""Fixed test sets: one data setting's samples from seeds that neither training nor validation draws.

A *test set* is one data setting, a terrain preset (``sim.presets``) at one image-noise
level, with ``size`` samples from the HDL-32E (by default) at the training defaults' map size
and cell, without augmentation. Its samples come from fixed seeds:

- training batch seeds lie in ``[0, 2**30)`` (``data.seeds.batch_seed``), validation uses
  ``2**30 + i`` for its ``i``-th chunk of 16 samples (``data.seeds.validation_seed``);
- test chunk ``i`` (samples ``16 i .. 16 i + 15``) uses seed ``TEST_SEED_BASE + i`` with
  ``TEST_SEED_BASE = 2**31 - 2**24``: the top 2**24 seeds of the 31 bits ``generate_batch``
  keeps. Validation would need more than a billion chunks to reach them.

Sample ``b`` of a chunk depends only on (setting, seed, b), so a quick run's samples are the
first samples of the full set, and every setting with the same terrain sees the same terrains
and scans, only the image noise differs. Settings with obstacles also get each sample's bare
ground (the same seed with every obstacle count set to zero: see ``metrics``).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from pathlib import Path

import torch

from ..data.seeds import TEST_SEED_BASE
from ..sim import SimConfig, generate_batch, lidar_preset, resolve_device
from ..sim.presets import preset_sim
from ..sim.terrain import OBSTACLE_KINDS, ObstacleConfig

__all__ = [
    "CHUNK",
    "DEFAULT_NOISE",
    "DEFAULT_SETTINGS",
    "DEFAULT_SIZE",
    "QUICK_SIZE",
    "TEST_SEED_BASE",
    "EvalSet",
    "bare_config",
    "eval_seeds",
    "make_eval_set",
    "setting_config",
    "setting_name",
]

#: Samples per generated chunk (chunk ``i`` is seed ``TEST_SEED_BASE + i``).
CHUNK = 16
#: The terrain settings, image-noise levels and samples per set of ``warp-terrain evaluate``.
DEFAULT_SETTINGS = ("octave3", "octave5", "flat_cylinders", "negative_obstacles")
DEFAULT_NOISE = (0.0, 0.05, 0.10)
DEFAULT_SIZE = 64
#: Samples per set of ``warp-terrain evaluate --quick``.
QUICK_SIZE = 4
POSITIVE_KINDS = ("cylinders", "boxes", "rocks")
NEGATIVE_KINDS = ("pits", "ditches")


def eval_seeds(size: int, chunk: int = CHUNK) -> list[int]:
    """The generator seeds of a test set of ``size`` samples (one per chunk of ``chunk``)."""
    if isinstance(size, bool) or not isinstance(size, int) or size < 1:
        raise ValueError(f"size={size!r}: must be an integer >= 1")
    if size > chunk * 2**24:
        raise ValueError(f"size={size}: at most {chunk * 2**24} samples (2**24 test seeds)")
    return [TEST_SEED_BASE + i for i in range(math.ceil(size / chunk))]


@dataclass
class EvalSet:
    """One data setting's fixed samples, on the CPU: ``(N, 1, S, S)`` tensors."""

    terrain: str
    noise: float
    sim: SimConfig
    seeds: list[int]
    scan: torch.Tensor
    mask: torch.Tensor
    target: torch.Tensor
    ground: torch.Tensor | None = None  # bare ground (obstacles removed), if the setting has obstacles
    positive: bool = False  # has cylinders / boxes / rocks
    negative: bool = False  # has pits / ditches
    extra: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return setting_name(self.terrain, self.noise)

    def __len__(self) -> int:
        return int(self.scan.shape[0])


def setting_name(terrain: str, noise: float) -> str:
    """A test set's name: ``<terrain>/noise<noise>``."""
    return f"{terrain}/noise{noise:g}"


def bare_config(sim: SimConfig) -> SimConfig:
    """``sim`` with every obstacle count set to zero (the same relief, sensor and maps)."""
    bare = copy.deepcopy(sim)
    for kind in OBSTACLE_KINDS:
        setattr(bare.terrain, kind, ObstacleConfig())
    return bare


def setting_config(terrain: str, noise: float = 0.0, lidar="hdl32e") -> SimConfig:
    """The ``SimConfig`` of a test setting: terrain ``conf/terrain/<terrain>.yaml`` (or a YAML
    path), ``lidar`` (a preset name or a ``LidarConfig``), image noise ``noise``, no augmentation,
    the training defaults' maps (121 x 121 cells of 0.25 m)."""

    if isinstance(noise, bool) or not isinstance(noise, (int, float)) or not 0.0 <= float(noise) <= 1.0:
        raise ValueError(f"noise={noise!r}: must be a number in [0, 1] (a fraction of the height range)")
    sim = preset_sim(terrain, augment=False)
    sim.lidar = lidar_preset(lidar) if isinstance(lidar, str) else copy.deepcopy(lidar)
    sim.data.noise = float(noise)
    sim.validate()
    return sim


def _has_any(sim: SimConfig, kinds: tuple[str, ...]) -> bool:
    """Whether ``sim``'s terrain may place an obstacle of one of ``kinds``."""
    return any(getattr(sim.terrain, k).count_max > 0 for k in kinds)


def make_eval_set(terrain: str, noise: float = 0.0, size: int = DEFAULT_SIZE, lidar="hdl32e", device=None, chunk: int = CHUNK) -> EvalSet:
    """Generate the fixed test set of one setting (see the module docstring for the seeds)."""
    sim = setting_config(terrain, noise, lidar)
    device = resolve_device(device)
    seeds = eval_seeds(size, chunk)
    positive, negative = _has_any(sim, POSITIVE_KINDS), _has_any(sim, NEGATIVE_KINDS)
    bare = bare_config(sim) if (positive or negative) else None
    parts: dict[str, list[torch.Tensor]] = {"scan": [], "mask": [], "target": [], "ground": []}
    for i, seed in enumerate(seeds):
        n = min(chunk, size - i * chunk)
        b = generate_batch(n, sim, seed=seed, device=device)
        for key in ("scan", "mask", "target"):
            parts[key].append(getattr(b, key).detach().cpu().clone())
        if bare is not None:
            parts["ground"].append(generate_batch(n, bare, seed=seed, device=device).target.detach().cpu().clone())
    return EvalSet(
        terrain=Path(terrain).stem,
        noise=float(noise),
        sim=sim,
        seeds=seeds,
        scan=torch.cat(parts["scan"]),
        mask=torch.cat(parts["mask"]),
        target=torch.cat(parts["target"]),
        ground=torch.cat(parts["ground"]) if bare is not None else None,
        positive=positive,
        negative=negative,
    )
