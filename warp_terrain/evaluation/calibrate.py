"""Calibrating a model's uncertainty on validation pairs (sigma scaling).

The log-variance head learns the squared error of the *training-mode* prediction (dropout on,
batch statistics), on the training distribution. The eval-mode prediction, averaged over 8
orientations, errs less, so its raw sigma is too large. One factor ``k`` fixes the scale:
``k^2 = mean(e^2 / sigma^2)`` over the unobserved cells of validation pairs, the factor that
minimises the Gaussian negative log-likelihood of those errors (Laves et al., 2020, "Well-
calibrated regression uncertainty in medical imaging with deep learning"). The pairs come from
validation seeds beyond those training validates on, so neither training nor the test sets
(``evaluation.testsets``) see them.

A model that checks each map on its own scan (``check_sigma``) scales each map's sigma by what
its check measured instead; a map whose check cannot measure its error (a noisy scan, whose
checked errors stand no higher than its noise) falls back to the file's calibration, and the
pooled factor, a mean of squares over every map, is about twice too wide there: the errors of a
model averaged over eight orientations and checked have heavier tails than the training-mode
errors the head learnt. ``fit_unresolved_sigma_scale`` fits that fallback on exactly those maps,
as the check fits the others: the factor that puts 68 % of their errors within 1 sigma.

``package_model`` (``warp-terrain package-model``) turns a training checkpoint into a small
``Reconstructor`` file, fitting that factor on the run's own data settings first.
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path

import torch

from ..data.stream import make_pair, validation_seed
from ..inference.reconstructor import Reconstructor
from ..inference.selfcheck import CANDIDATE_TENSIONS, SIGMA_COVERAGE, THIN_PLATE_ONLY
from ..models import build_generator
from ..sim import SimConfig, as_sim_config

#: First validation chunk used for calibration (training validates on chunks 0, 1, ...).
CALIBRATION_FIRST_CHUNK = 4096


def fit_sigma_scale(rec, sim: SimConfig, size: int = 256, device: str = "cpu", chunk: int = 16) -> float:
    """The factor ``k`` that makes ``k * sigma`` the RMS error of ``rec`` on the unobserved cells
    of ``size`` validation pairs of ``sim`` (with ``rec``'s own TTA setting, from ``sigma_scale = 1``)."""
    if not rec.has_uncertainty:
        raise ValueError("this model has no uncertainty head (model.uncertainty=false): nothing to calibrate")
    if isinstance(size, bool) or not isinstance(size, int) or size < 1:
        raise ValueError(f"size={size!r}: must be an integer >= 1")
    saved = rec.meta.pop("sigma_scale", None)
    try:
        total, cells = 0.0, 0
        for i in range(0, size, chunk):
            pair = make_pair(sim, min(chunk, size - i), validation_seed(CALIBRATION_FIRST_CHUNK + i // chunk), device)
            height, sigma = rec.predict_maps_with_uncertainty(pair["scan"], pair["mask"])
            unobserved = pair["mask"].to(height.device) <= 0
            ratio = (height.double() - pair["target"].to(height.device).double()) / sigma.double()
            total += float(ratio[unobserved].square().sum())
            cells += int(unobserved.sum())
    finally:
        if saved is not None:
            rec.meta["sigma_scale"] = saved
    if cells == 0:
        raise ValueError("no unobserved cell in the calibration pairs")
    return math.sqrt(total / cells)


def fit_unresolved_sigma_scale(rec, sim: SimConfig, size: int = 256, device: str = "cpu", chunk: int = 16,
                               coverage: float = SIGMA_COVERAGE) -> float | None:
    """The sigma factor (on the raw sigma, as ``sigma_scale`` is) of the maps whose self-check
    cannot measure their error: ``sigma_scale`` times the ``coverage`` quantile of ``|e| /
    sigma`` over the unobserved cells where such a map's fallback applies (the cells nearer the
    scan than halfway to ``selfcheck.REACH_FAR`` for a map unresolved near it, the others for one
    unresolved far from it), on ``size`` validation pairs of ``sim`` (the same pairs as
    :func:`fit_sigma_scale`). ``rec`` checks its maps and their sigma (``self_check``,
    ``check_sigma``) as the file will. None when no map of the pairs is unresolved."""
    if not (rec.self_check and rec.check_sigma and rec.has_uncertainty):
        raise ValueError("fit_unresolved_sigma_scale: needs a model that checks its sigma on its own scans "
                         "(self_check, check_sigma, an uncertainty head)")
    if isinstance(size, bool) or not isinstance(size, int) or size < 1:
        raise ValueError(f"size={size!r}: must be an integer >= 1")
    ratios = []
    with torch.inference_mode():
        for i in range(0, size, chunk):
            pair = make_pair(sim, min(chunk, size - i), validation_seed(CALIBRATION_FIRST_CHUNK + i // chunk), device)
            scan, mask, target = (pair[key].to(rec.device) for key in ("scan", "mask", "target"))
            checked = rec.check_maps(scan, mask)
            (_, near), away = checked.factors
            far = checked.regimes.far(mask) >= 0.5
            fallback = ~near.view(-1, 1, 1, 1) & ~far
            if away is not None:
                fallback |= ~away[1].view(-1, 1, 1, 1) & far
            cells = fallback & (mask <= 0)
            ratios.append(((checked.height - target).abs() / checked.sigma)[cells].float().cpu())
    ratios = torch.cat(ratios)
    if ratios.numel() == 0:
        return None
    return rec.sigma_scale * float(torch.quantile(ratios.double(), coverage))


def with_observed_bound_noise(rec, factor: float):
    """``rec`` with its generator's bound on observed cells widened to ``factor`` times each
    scan's noise (``model.observed_bound_noise``): the same weights, the config changed."""
    if isinstance(factor, bool) or not isinstance(factor, (int, float)):
        raise ValueError(f"observed_bound_noise={factor!r}: expected a finite number >= 0")
    cfg = dataclasses.replace(rec.model_config, observed_bound_noise=float(factor)).validate()
    if not cfg.residual:
        raise ValueError("observed_bound_noise: needs a fill-residual model (model.residual=true)")
    generator = build_generator(cfg)
    generator.load_state_dict(rec.generator.state_dict())
    return Reconstructor(generator, cfg, rec.meta, device=rec.device, tta=rec.tta, self_check=rec.self_check,
                         check_reach=rec.check_reach, check_sigma=rec.check_sigma, check_keep_far=rec.check_keep_far,
                         centre_cells=rec.centre_cells, check_keep_shadows=rec.check_keep_shadows, check_keep_large=rec.check_keep_large)


def package_model(checkpoint: str | os.PathLike, out: str | os.PathLike, calibrate: int = 256, device=None, self_check: bool = False,
                  check_reach: bool = False, check_sigma: bool = False, check_membrane: bool = False,
                  check_keep_far: bool = False, observed_bound_noise: float | None = None, check_cycles: int = 0,
                  check_keep_shadows: bool = False, check_keep_large: bool = False) -> dict:
    """Write the generator of ``checkpoint`` (a training checkpoint or a ``Reconstructor`` file)
    to ``out`` as a ``Reconstructor`` file (fp16 weights, model config, run config); with
    ``calibrate`` > 0 and an uncertainty head, first fit its ``sigma_scale`` on ``calibrate``
    validation pairs of the run's own data settings (:func:`fit_sigma_scale`).

    ``self_check``: the file asks ``Reconstructor`` to check every map on its own scan
    (``meta["self_check"]``; only a fill-residual generator has the fills to fall back to).
    ``check_reach``: the check's weight holds near the scan only, the weight measured on the
    scan's outer cells far from it (``meta["check_reach"]``, ``inference/selfcheck.py``); needs ``self_check``.
    ``check_sigma``: each map's sigma is scaled on the check's own cells (``meta["check_sigma"]``,
    ``selfcheck.sigma_factor``); needs ``self_check`` and an uncertainty head.
    ``check_membrane``: the check also weighs the membrane (``meta["check_tensions"] = (0, 1)``,
    ``selfcheck.checked_maps``); needs ``self_check``.
    ``check_keep_far``: far from the scan the check keeps the net's correction whole instead of
    weighing it on the outer cells (``meta["check_keep_far"]``); needs ``check_reach``.
    ``check_cycles``: multigrid V-cycles on the thin plates the check weighs, after the cascade
    (``meta["check_cycles"]``, ``biharmonic.v_cycles``); needs ``self_check``.
    ``check_keep_shadows``: the check keeps the net's correction whole in the scan's shadows
    unless its cells refute the scan's horizon (``meta["check_keep_shadows"]``,
    ``inference/shadows.py``); needs ``self_check``.
    ``check_keep_large``: the check keeps a correction of an obstacle's size whole on the
    unobserved cells unless its hidden cells measure such corrections (``meta["check_keep_large"]``,
    ``selfcheck.large_weight``); needs ``self_check``.

    ``observed_bound_noise`` (None: as the file's model is): the generator's bound on observed
    cells widened to that many times each scan's noise (``model.observed_bound_noise``; it holds
    no weight, so a net trained without it takes it as it is); needs ``model.observed_bound`` > 0.

    With ``check_sigma`` and ``calibrate`` the file also gets ``sigma_scale_unresolved``
    (:func:`fit_unresolved_sigma_scale` on the same pairs, checked as the file will check).

    Returns ``{"out", "bytes", "step", "sigma_scale", "sigma_scale_unresolved", "observed_bound_noise", "self_check", "check_reach", "check_sigma", "check_membrane",
    "check_keep_far", "check_cycles", "check_keep_shadows", "check_keep_large"}``
    (``sigma_scale`` None if not fitted).
    """
    if isinstance(calibrate, bool) or not isinstance(calibrate, int) or calibrate < 0:
        raise ValueError(f"calibrate={calibrate!r}: must be an integer >= 0")
    out = Path(out)
    if not out.resolve().parent.is_dir():
        raise ValueError(f"out={str(out)!r}: the folder does not exist")
    if check_reach and not self_check:
        raise ValueError("check_reach: needs self_check (it sets how far the self-check's weight holds)")
    if check_keep_far and not check_reach:
        raise ValueError("check_keep_far: needs check_reach (it sets the check's weight far from the scan)")
    if check_membrane and not self_check:
        raise ValueError("check_membrane: needs self_check (the membrane is one of the self-check's fills)")
    if isinstance(check_cycles, bool) or not isinstance(check_cycles, int) or check_cycles < 0:
        raise ValueError(f"check_cycles={check_cycles!r}: must be an integer >= 0")
    if check_cycles and not self_check:
        raise ValueError("check_cycles: needs self_check (the cycles solve the self-check's thin plates further)")
    if check_keep_shadows and not self_check:
        raise ValueError("check_keep_shadows: needs self_check (it sets the self-check's weight in the scan's shadows)")
    if check_keep_large and not self_check:
        raise ValueError("check_keep_large: needs self_check (it sets the self-check's weight of the large corrections)")
    if check_sigma and not self_check:
        raise ValueError("check_sigma: needs self_check (the sigma is scaled on the self-check's cells)")
    rec = Reconstructor.load(checkpoint, device=device, self_check=False)
    if observed_bound_noise is not None:
        rec = with_observed_bound_noise(rec, observed_bound_noise)
    if self_check and not hasattr(rec.generator, "base_fill"):
        raise ValueError(f"{str(checkpoint)!r}: self_check needs a fill-residual model (model.residual=true)")
    if check_sigma and not rec.has_uncertainty:
        raise ValueError(f"{str(checkpoint)!r}: check_sigma needs a model with an uncertainty head (model.uncertainty=true)")
    if calibrate and rec.has_uncertainty:
        run = rec.meta.get("config") or {}
        if not all(key in run for key in ("terrain", "lidar", "data")):
            raise ValueError(f"{str(checkpoint)!r}: holds no run config to calibrate on (use --calibrate 0)")
        sim = as_sim_config({key: run[key] for key in ("terrain", "lidar", "data")})
        rec.meta["sigma_scale"] = fit_sigma_scale(rec, sim, calibrate, device=rec.device)
    rec.meta["self_check"] = bool(self_check)
    rec.meta["check_reach"] = bool(check_reach)
    rec.meta["check_sigma"] = bool(check_sigma)
    rec.meta["check_keep_far"] = bool(check_keep_far)
    rec.meta["check_tensions"] = list(CANDIDATE_TENSIONS if check_membrane else THIN_PLATE_ONLY)
    rec.meta["check_cycles"] = int(check_cycles)
    rec.meta["check_keep_shadows"] = bool(check_keep_shadows)
    rec.meta["check_keep_large"] = bool(check_keep_large)
    if not check_sigma:
        rec.meta.pop("sigma_scale_unresolved", None)
    elif calibrate:  # the fallback of the maps the check cannot resolve, fitted on them as the file checks them
        checked = Reconstructor(rec.generator, rec.model_config, rec.meta, device=rec.device)
        unresolved = fit_unresolved_sigma_scale(checked, sim, calibrate, device=rec.device)
        if unresolved is None:
            rec.meta.pop("sigma_scale_unresolved", None)
        else:
            rec.meta["sigma_scale_unresolved"] = unresolved
    rec.save(out)
    return {"out": str(out), "bytes": out.stat().st_size, "step": rec.meta.get("step"), "sigma_scale": rec.meta.get("sigma_scale"),
            "sigma_scale_unresolved": rec.meta.get("sigma_scale_unresolved"),
            "observed_bound_noise": rec.model_config.observed_bound_noise,
            "self_check": bool(self_check), "check_reach": bool(check_reach), "check_sigma": bool(check_sigma),
            "check_membrane": bool(check_membrane), "check_keep_far": bool(check_keep_far), "check_cycles": int(check_cycles),
            "check_keep_shadows": bool(check_keep_shadows), "check_keep_large": bool(check_keep_large)}
