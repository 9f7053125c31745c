"""``Reconstructor``: a trained generator that turns any point cloud into an elevation map."""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import partial
from importlib import resources
from pathlib import Path

import numpy as np
import torch

from ..core.geometry import MAP_SIZE, MapGeometry
from ..core.torchfile import atomic_save, read_error
from ..models import ModelConfig, build_generator
from ..models.biharmonic import v_cycles
from ..models.centring import centre_cells
from ..models.uncertainty import split_output
from ..sim.device import resolve_device
from ..sim.projection import cell_offsets, check_map, project_points
from .pointclouds import check_points
from .selfcheck import LARGE_CORRECTION, SHADOW_MARGIN, THIN_PLATE_ONLY, Regimes, check_cells, checked_maps, resolved_sigma_factor, scan_noise

PRETRAINED = "reconstructor.pt"


def pretrained_path() -> Path:
    """Where the model shipped inside the package lies."""
    return Path(str(resources.files("warp_terrain") / "pretrained" / PRETRAINED))


#: The eight orientations of a square map: (quarter turns, mirrored).
DIHEDRAL = tuple((turns, mirror) for turns in range(4) for mirror in (False, True))


def _orient(x: torch.Tensor, turns: int, mirror: bool) -> torch.Tensor:
    x = torch.rot90(x, turns, dims=(2, 3))
    return x.flip(3) if mirror else x


def _unorient(x: torch.Tensor, turns: int, mirror: bool) -> torch.Tensor:
    x = x.flip(3) if mirror else x
    return torch.rot90(x, -turns, dims=(2, 3))


@dataclass
class CheckedMaps:
    """What ``Reconstructor.check_maps`` measured: ``height`` (B, 1, S, S), the checked maps;
    ``sigma`` their sigma at the file's own calibration (``sigma_scale``; None without an
    uncertainty head); ``regimes``, where each measured weight holds; ``factors``, with
    ``check_sigma``, per regime ``(near, away)`` the ``(k, resolved)`` of
    ``selfcheck.resolved_sigma_factor`` (``away`` None without the reach), else None."""

    height: torch.Tensor
    sigma: torch.Tensor | None
    regimes: Regimes
    factors: tuple | None


class Reconstructor:
    """A generator with what it needs to read a point cloud: ``reconstruct(points) -> map``.

    ``Reconstructor.load()`` loads the model shipped in the package (trained by this project's
    ``train.py``; its run config lies beside it); ``Reconstructor.load(path)`` a file written by
    ``Reconstructor.save`` or a training checkpoint. Files load with ``weights_only=True``.

    ``tta`` (test-time augmentation, on by default): every map is also predicted in its seven
    other orientations (quarter turns and mirror images: a LIDAR's scan of a turned or mirrored
    world is the turned or mirrored scan, and training augments with the same eight) and the
    eight predictions are averaged, mapped back. Eight times the network's work (a few ms per
    map on a CPU) for a few per cent lower error (README, "Evaluation"). The uncertainty is then
    the members' RMS sigma: an average errs less than its members, so it errs on the safe side.

    The uncertainty is multiplied by ``meta["sigma_scale"]`` (1 if absent): a factor fitted on
    validation pairs when the model is packaged (:func:`~warp_terrain.evaluation.calibrate.fit_sigma_scale`).
    With ``check_sigma`` (and the self-check) each map's sigma is instead scaled on its own scan:
    by the factor that puts 68 % of the check's hidden cells within 1 sigma (``selfcheck.sigma_factor``),
    the measured heights' own noise taken out (``selfcheck.scan_noise``): the sigma is about the
    ground, not about the scan's noise. A map whose check cannot measure its error (too few
    hidden cells, or errors hidden under the scan's noise) takes ``meta["sigma_scale_unresolved"]``
    instead, where the file has it: the factor fitted on the calibration maps the check could not
    resolve (:func:`~warp_terrain.evaluation.calibrate.fit_unresolved_sigma_scale`); else ``sigma_scale``.

    ``centre_cells`` (off unless the file says so): a cloud's cells are moved from their returns'
    mean position to their centres before the model sees them (``models.centring``): on
    simulated scans the shipped model's unobserved-cell error is 2-5 % lower so on clean smooth
    ground and level on noisy scans and real sweeps, but the checked sigma, calibrated on mean
    heights, narrows too much on smooth ground (docs/transfer.md, stop 34).
    Only ``reconstruct*`` (from points) can do it: a map alone does not say where its returns lay.
    """

    def __init__(self, generator: torch.nn.Module, model_config: ModelConfig, meta: dict | None = None, device=None, tta: bool = True,
                 self_check: bool | None = None, check_reach: bool | None = None, check_sigma: bool | None = None,
                 check_keep_far: bool | None = None, centre_cells: bool | None = None, check_cycles: int | None = None,
                 check_keep_shadows: bool | None = None, check_keep_large: bool | None = None):
        self.device = resolve_device(device)
        self.generator = generator.to(self.device).eval()
        if self.device == "cpu":
            # oneDNN's convolutions run channels-last without reordering each layer's input: the
            # ngf-32 U-Net of one checked map min 16.5 -> 13.6 ms on two threads here
            # (tools/probes/channels_last_ab.py)
            self.generator.to(memory_format=torch.channels_last)
        self.model_config = model_config
        self.meta = dict(meta or {})
        self.tta = bool(tta)
        # each check setting: None means as the model file says (``meta[key]``, set when it was packaged)
        def setting(key: str, value: bool | None) -> bool:
            return bool(self.meta.get(key, False)) if value is None else bool(value)

        self.self_check = setting("self_check", self_check) and hasattr(self.generator, "base_fill")
        # the checked weight holds only near the scan; far from it the weight measured on the
        # scan's outer cells (``selfcheck.py``)
        self.check_reach = setting("check_reach", check_reach)
        # with the reach: far from the scan the correction is kept whole, not weighed on the outer
        # cells (which lie next to kept ones)
        self.check_keep_far = setting("check_keep_far", check_keep_far)
        # the correction kept whole in the scan's shadows, where the check's cells (all seen) cannot measure it
        self.check_keep_shadows = setting("check_keep_shadows", check_keep_shadows)
        # a correction of an obstacle's size kept whole off the scan, unless the check's hidden cells measure such ones
        self.check_keep_large = setting("check_keep_large", check_keep_large)
        # each map's sigma scaled on the check's hidden cells
        self.check_sigma = setting("check_sigma", check_sigma)
        # the plain fills the check weighs beside the base fill, by tension (thin plate 0, membrane 1):
        # as the model file says (``meta["check_tensions"]``); files from before the membrane: the thin plate only
        self.check_tensions = tuple(float(t) for t in self.meta.get("check_tensions", THIN_PLATE_ONLY))
        # multigrid V-cycles on the thin plates the check weighs, after the cascade (``v_cycles``):
        # as the file says (``meta["check_cycles"]``); files from before them: none
        self.check_cycles = int(self.meta.get("check_cycles", 0)) if check_cycles is None else check_cycles
        if isinstance(self.check_cycles, bool) or not isinstance(self.check_cycles, int) or self.check_cycles < 0:
            raise ValueError(f"check_cycles must be an integer >= 0, got {self.check_cycles!r}")
        # a cloud's cells moved to their centres before the model sees them (``reconstruct*`` only):
        # as the file says, else as the model was trained (``model.centre_cells``)
        trained = bool(self.meta.get("centre_cells", model_config.centre_cells))
        self.centre_cells = trained if centre_cells is None else bool(centre_cells)

    # -- files --------------------------------------------------------------------------------
    @classmethod
    def load(cls, path: str | os.PathLike | None = None, device=None, tta: bool = True, self_check: bool | None = None,
             check_reach: bool | None = None, check_sigma: bool | None = None, check_keep_far: bool | None = None,
             centre_cells: bool | None = None, check_cycles: int | None = None, check_keep_shadows: bool | None = None,
             check_keep_large: bool | None = None) -> Reconstructor:
        path = pretrained_path() if path is None else Path(path)
        if not path.is_file():
            raise ValueError(f"model file {str(path)!r} does not exist")
        try:
            state = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as err:
            raise ValueError(f"model file {str(path)!r} cannot be read ({read_error(err)})") from None
        if "model" in state and "netG" in state["model"]:  # a training checkpoint
            cfg = ModelConfig.coerce(state["model"]["config"])
            weights, meta = state["model"]["netG"], {"config": state.get("config", {}), "step": state.get("step")}
        elif "netG" in state and "model_config" in state:
            cfg = ModelConfig.coerce(state["model_config"])
            weights, meta = state["netG"], state.get("meta", {})
        else:
            raise ValueError(f"model file {str(path)!r} holds neither a Reconstructor nor a training checkpoint")
        generator = build_generator(cfg)
        generator.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in weights.items()})
        return cls(generator, cfg, meta, device, tta, self_check, check_reach, check_sigma, check_keep_far, centre_cells, check_cycles,
                   check_keep_shadows, check_keep_large)

    def save(self, path: str | os.PathLike, half: bool = True) -> None:
        """Write the generator (fp16 weights by default: half the size) and its config, atomically."""
        weights = {k: (v.half() if half and v.is_floating_point() else v).cpu().contiguous() for k, v in self.generator.state_dict().items()}
        atomic_save({"netG": weights, "model_config": self.model_config.to_dict(), "meta": self.meta}, path)

    # -- inference ----------------------------------------------------------------------------
    def condition(self, scan: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return scan if self.model_config.in_channels == 1 else torch.cat([scan, mask], dim=1)

    @property
    def sigma_scale(self) -> float:
        """The calibration factor of the uncertainty (``meta["sigma_scale"]``, default 1)."""
        return float(self.meta.get("sigma_scale", 1.0))

    @property
    def has_uncertainty(self) -> bool:
        """Whether the model also predicts each cell's uncertainty (``model.uncertainty``)."""
        return bool(self.model_config.uncertainty)

    def predict_maps(self, scan: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """(B, 1, S, S) scan images and masks -> (B, 1, S, S) elevation maps."""
        return self.predict_maps_with_uncertainty(scan, mask)[0]

    def predict_maps_with_uncertainty(self, scan: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """``(elevation maps, standard deviations in metres or None)``, each (B, 1, S, S).

        With ``self_check`` each map keeps only the share of the net's correction that the
        map's own scan supports (``inference/selfcheck.py``): the model's map of the scan with a
        fifth of its observed cells hidden is compared there with classical fills (its base
        fill, the plain thin plate and the membrane), and the map is the best fill plus that share. With
        ``check_reach`` the same pass also hides the scan's outermost observed cells
        (``outer_cells``): the share measured on the random cells holds near the scan, and with
        distance from it (``far_share``) gives way to the share measured on the outer cells, or
        with ``check_keep_far`` to the whole correction. With ``check_keep_shadows`` the correction
        is also kept whole in the scan's shadows (``inference/shadows.py``), where the check's
        cells, all seen by the sensor, cannot measure it, unless the check's cells refute the
        scan's horizon (``selfcheck.shadow_weight``). With ``check_keep_large`` a correction of an
        obstacle's size (``selfcheck.LARGE_CORRECTION``) is kept whole on the unobserved cells, unless
        the check's hidden cells carry such corrections and so measure them (``selfcheck.large_weight``).
        With ``check_sigma`` the sigma of each map is scaled so that 68 % of the checked cells'
        errors (the thinned scan's map, blended as the full one is) lie within 1 sigma: the
        factor of the random cells near the scan, that of the outer cells far from it (with the reach);
        each checked error less the scan's own noise (``scan_noise``), which the hidden
        measurements carry and the ground does not.

        Computed in ``torch.inference_mode`` (one map with the check: about 10 ms less than under
        ``no_grad`` on this CPU) and returned as plain tensors, which the caller may update in place."""
        with torch.inference_mode():
            height, sigma = self._predict_checked(scan.to(self.device), mask.to(self.device))
        return height.clone(), None if sigma is None else sigma.clone()

    @property
    def unresolved_sigma_factor(self) -> float:
        """The factor, on top of ``sigma_scale``, of a map whose check cannot measure its error:
        ``meta["sigma_scale_unresolved"] / sigma_scale`` (1 for a file without it)."""
        return float(self.meta.get("sigma_scale_unresolved", self.sigma_scale)) / self.sigma_scale

    def _predict_checked(self, scan: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """``predict_maps_with_uncertainty`` of inputs on the model's device, without grad."""
        if not self.self_check:
            return self._predict(scan, mask)[:2]
        checked = self.check_maps(scan, mask)
        if checked.factors is None:
            return checked.height, checked.sigma
        fallback = self.unresolved_sigma_factor
        factors = tuple(None if f is None else torch.where(f[1].view(-1, 1, 1, 1), f[0], torch.full_like(f[0], fallback))
                        for f in checked.factors)
        return checked.height, checked.sigma * checked.regimes.at(factors, mask)

    def check_maps(self, scan: torch.Tensor, mask: torch.Tensor) -> CheckedMaps:
        """The self-check's parts of inputs on the model's device (call it without grad): the
        checked maps, their sigma before the check scales it and, with ``check_sigma``, the
        per-map factors each regime measured (``selfcheck.resolved_sigma_factor``)."""
        hidden, outer, thinned = check_cells(mask, self.check_reach)  # one pass answers both checks
        # the scan and its thinned copy go through the net, and their classical fills through one solve, together
        n = scan.shape[0]
        both_scans, both_masks = torch.cat([scan, scan * thinned]), torch.cat([mask, thinned])
        # both scans' noise once: the generator's bound takes both, the sigma the full scans' (each map's own median)
        needs_noise = (bool(getattr(self.generator, "noise_bound", 0)) or (self.check_sigma and self.has_uncertainty)
                       or self.check_keep_shadows)
        noise = scan_noise(both_scans, both_masks) if needs_noise else None
        heights, sigmas, fills = self._predict(both_scans, both_masks, self.check_tensions, noise=noise)
        regimes = Regimes(hidden, outer if self.check_reach else None, masks=(mask, thinned))
        height, height_thinned = checked_maps(fills, heights, scan, mask, thinned, regimes, self.check_membrane,
                                              self.check_keep_far, SHADOW_MARGIN * noise if self.check_keep_shadows else None,
                                              LARGE_CORRECTION if self.check_keep_large else None)
        sigma, factors = None if sigmas is None else sigmas[:n], None
        if sigma is not None and self.check_sigma:  # measured on the cells the thinned map did not see, per regime
            factor = partial(resolved_sigma_factor, noise=noise[:n])  # about the ground, not the scan's noise
            factors = regimes.measure(factor, height_thinned, sigmas[n:], scan)
        return CheckedMaps(height, sigma, regimes, factors)

    @property
    def check_membrane(self) -> bool:
        """Whether the check weighs the membrane (the last of ``check_tensions`` is 1, after the thin plate)."""
        return len(self.check_tensions) > 1 and self.check_tensions[-1] == 1.0

    def _predict(self, scan: torch.Tensor, mask: torch.Tensor, tensions: tuple[float, ...] = (), noise: torch.Tensor | None = None
                 ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """``(height, sigma, fills)``: the generator's maps averaged over the orientations, and
        (None for a generator without a base fill) the classical fills of the maps as they are,
        (1 + len(tensions), B, 1, S, S): the base fill, then the plain fill under each of
        ``tensions``, solved with the orientations' base fills in one batch; the self-check
        weighs them instead of solving them again. ``noise``: the scans' ``scan_noise`` if the
        caller has it (else computed here when the generator's bound needs it)."""
        orientations = DIHEDRAL if self.tta else DIHEDRAL[:1]  # DIHEDRAL[0]: as the map is
        # all orientations as one batch (the generator is in eval mode: maps do not interact)
        condition = self.condition(scan, mask)
        turned = torch.cat([_orient(condition, turns, mirror) for turns, mirror in orientations])
        fills = None
        if hasattr(self.generator, "base_fill"):
            bases, plain = self.generator.base_and_plain_fills(turned[:, :1], turned[:, 1:2], tensions, count=scan.shape[0])
            plain = self._cycled(plain, mask, tensions)
            # the scans' noise once, not per orientation (it is a median of second differences, which turning keeps)
            if getattr(self.generator, "noise_bound", 0):
                noise = (scan_noise(scan, mask) if noise is None else noise).repeat(len(orientations), 1, 1, 1)
            else:
                noise = None
            outputs, fills = self.generator(turned, fill=bases, noise=noise), torch.cat([bases[None, : scan.shape[0]], plain])
        else:
            outputs = self.generator(turned)
        heights, variances = [], []
        for (turns, mirror), output in zip(orientations, outputs.chunk(len(orientations))):
            height, log_variance = split_output(_unorient(output, turns, mirror), self.has_uncertainty)
            heights.append(height)
            if log_variance is not None:
                variances.append(log_variance.exp())
        height = torch.stack(heights).mean(dim=0)
        sigma = self.sigma_scale * torch.stack(variances).mean(dim=0).sqrt() if variances else None
        return height, sigma, fills

    def _cycled(self, plain: torch.Tensor, mask: torch.Tensor, tensions: tuple[float, ...]) -> torch.Tensor:
        """The plain fills (len(tensions), B, 1, S, S) of maps observed at ``mask``, each thin plate
        (tension 0) given ``check_cycles`` multigrid V-cycles (``v_cycles``): the cascade stops short
        of the thin plate in wide gaps between a sparse scan's rings, and there the check would
        weigh an unfinished fill (docs/transfer.md, stop 40). The membrane is left as it is: the
        cascade nearly finishes it (on the OS-0-32 sweep 5 cm RMS from the direct solve within 6
        cells of the scan, the thin plate 2.4 m), and its exact solve changed no check there."""
        thin = [i for i, t in enumerate(tensions) if t == 0.0]
        if not self.check_cycles or not thin:
            return plain
        plain = plain.clone()
        plain[thin] = v_cycles(plain[thin].flatten(0, 1), mask.repeat(len(thin), 1, 1, 1), self.check_cycles).view(
            len(thin), *plain.shape[1:])
        return plain

    @property
    def geometry(self) -> MapGeometry:
        """The map the model was trained on (its stored run config's ``data``), else 121 x 0.25 m."""
        data = (self.meta.get("config") or {}).get("data") or {}
        default = MapGeometry()
        return MapGeometry(int(data.get("map_size", default.size)), float(data.get("map_cell", default.cell)))

    def resolve_geometry(self, map_size: int | None, map_cell: float | None) -> tuple[int, float]:
        """``(map_size, map_cell)``: the given values, or the model's where None."""
        g = self.geometry
        return (g.size if map_size is None else map_size), (g.cell if map_cell is None else map_cell)

    def reconstruct(self, points, map_size: int | None = None, map_cell: float | None = None) -> np.ndarray:
        """``(map_size, map_size)`` float32 elevation map (sensor frame) from an ``(N, 3)`` cloud.

        ``map_size`` / ``map_cell`` default to the map the model was trained on (:attr:`geometry`:
        121 cells of 0.25 m for the shipped model).

        Points are in the sensor frame (gravity-aligned, origin at the LIDAR). Rows with NaN/inf
        are dropped with a warning; an empty cloud, a wrong shape or dtype raise ValueError.
        """
        return self.reconstruct_with_mask(points, map_size, map_cell)[0]

    def reconstruct_with_mask(self, points, map_size: int | None = None, map_cell: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The map and the observation mask it was filled from, projecting the cloud once."""
        result = self.reconstruct_all(points, map_size, map_cell)
        return result["height"], result["mask"]

    def reconstruct_all(self, points, map_size: int | None = None, map_cell: float | None = None) -> dict[str, np.ndarray]:
        """``{"height", "mask"}`` and, if the model has an uncertainty head, ``"uncertainty"``
        (each cell's standard deviation of the height, metres): ``(map_size, map_size)`` arrays."""
        map_size, map_cell = self.resolve_geometry(map_size, map_cell)
        check_map(map_size, map_cell)
        if self.model_config.name == "paper" and map_size != MAP_SIZE:
            raise ValueError(f"map_size={map_size}: this model is the paper's net for 121x121 maps")
        xyz = check_points(points)
        scan, mask = project_points(xyz, map_size=map_size, map_cell=map_cell, device=self.device)
        if mask.sum() == 0:
            raise ValueError(f"points: none of the {len(xyz)} points falls inside the {map_size}x{map_size} map of {map_cell} m cells")
        if self.centre_cells:
            scan = centre_cells(scan, mask, cell_offsets(xyz, map_size=map_size, map_cell=map_cell, device=self.device), map_cell)
        height, sigma = self.predict_maps_with_uncertainty(scan, mask)
        out = {"height": height[0, 0].float().cpu().numpy(), "mask": mask[0, 0].cpu().numpy()}
        if sigma is not None:
            out["uncertainty"] = sigma[0, 0].float().cpu().numpy()
        return out
