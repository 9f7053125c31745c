"""One predictor type: ``predictor(scan, mask)`` -> heights, or ``(heights, sigma)``.

Everything that scores, draws or exports a model's maps takes a :class:`Predictor`. There are
two ways to make one: :func:`load_predictor` from a file (a training checkpoint, a packaged
``Reconstructor`` file, or ``None`` for the model shipped in the package), and
:func:`model_predictor` from a model object in memory (a training run's ``Pix2PixModel``).
A classical fill (``evaluation.baselines``) is any callable with the same signature.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import torch

from ..models.inputs import model_input
from ..sim import SimConfig, as_sim_config
from .reconstructor import Reconstructor, pretrained_path

Output = torch.Tensor | tuple[torch.Tensor, torch.Tensor]


class Predictor:
    """``(B, 1, S, S)`` scan images and masks -> heights (and each cell's sigma if known).

    - ``in_channels``: what the net reads (1: the scan; 2: scan and mask)
    - ``sim``: the terrain, LIDAR and map settings the model was trained on (None if unknown)
    - ``info``: a short description for reports (file, step, generator, TTA, ...)
    """

    def __init__(self, predict: Callable[[torch.Tensor, torch.Tensor], Output], in_channels: int,
                 sim: SimConfig | None = None, info: dict | None = None):
        self._predict = predict
        self.in_channels = int(in_channels)
        self.sim = sim
        self.info = dict(info or {})

    def __call__(self, scan: torch.Tensor, mask: torch.Tensor) -> Output:
        return self._predict(scan, mask)


def _chunks(n: int, chunk: int) -> range:
    return range(0, n, chunk)


def model_predictor(model, in_channels: int, chunk: int = 16, sim: SimConfig | None = None) -> Predictor:
    """A model with ``predict(condition) -> (B, 1, S, S)`` heights (e.g. ``Pix2PixModel``), the
    condition built by ``models.model_input``; inputs go to the model's device, ``chunk`` maps at a time."""
    device = getattr(model, "device", None)

    @torch.no_grad()
    def predict(scan: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        outs = []
        for i in _chunks(scan.shape[0], chunk):
            s, m = scan[i : i + chunk], mask[i : i + chunk]
            if device is not None:
                s, m = s.to(device), m.to(device)
            outs.append(model.predict(model_input(s, m, in_channels)).float())
        return torch.cat(outs).to(scan.device)

    return Predictor(predict, in_channels, sim, {"generator": type(model).__name__})


def _trained_sim(meta: dict) -> SimConfig | None:
    """The run's simulator settings (its sensor, maps, world), or None. The DEM rasters a run
    trained on are not loaded: a model is used where they are not (the shipped model trained on
    ``real_data/``'s Finland raster, which a user's machine need not have)."""
    run = meta.get("config") or {}
    if not all(key in run for key in ("terrain", "lidar", "data")):
        return None
    return as_sim_config({key: run[key] for key in ("terrain", "lidar", "data")}, files=False)


def reconstructor_predictor(rec: Reconstructor, chunk: int = 16, path=None) -> Predictor:
    """A :class:`~warp_terrain.inference.reconstructor.Reconstructor` as a predictor. A predictor
    sees maps, which do not say where their returns lay: a model that centres a cloud's cells
    (``centre_cells``) is given the mean heights, with a warning."""
    if rec.centre_cells:
        warnings.warn("this model centres a cloud's cells (centre_cells), which maps alone do not allow: it is given "
                      "their mean heights (tools/probes/cell_centre.py scores it on centred cells)", stacklevel=2)

    def predict(scan: torch.Tensor, mask: torch.Tensor) -> Output:
        outs = [rec.predict_maps_with_uncertainty(scan[i : i + chunk], mask[i : i + chunk]) for i in _chunks(scan.shape[0], chunk)]
        height = torch.cat([h.float() for h, _ in outs]).to(scan.device)
        if not rec.has_uncertainty:
            return height
        return height, torch.cat([s.float() for _, s in outs]).to(scan.device)

    info = {
        "checkpoint": str(path if path is not None else pretrained_path()),
        "step": rec.meta.get("step"),
        "in_channels": rec.model_config.in_channels,
        "generator": rec.model_config.name,
        "residual": rec.model_config.residual,
        "uncertainty": rec.has_uncertainty,
        "tta": rec.tta,
        "self_check": rec.self_check,
    }
    return Predictor(predict, rec.model_config.in_channels, _trained_sim(rec.meta), info)


def load_predictor(path=None, device=None, chunk: int = 16, tta: bool = True, self_check: bool | None = None,
                   check_reach: bool | None = None, check_sigma: bool | None = None) -> Predictor:
    """The predictor of a training checkpoint (``checkpoints/best.pt``), a ``Reconstructor`` file,
    or (``path=None``) the model shipped in the package; ``tta``: average the 8 orientations;
    ``self_check``: check each map on its own scan, ``check_reach``: the check's weight near the
    scan only, ``check_sigma``: each map's sigma scaled on the check's cells (``Reconstructor``;
    None: as the file says)."""
    rec = Reconstructor.load(path, device=device, tta=tta, self_check=self_check, check_reach=check_reach, check_sigma=check_sigma)
    return reconstructor_predictor(rec, chunk, path)
