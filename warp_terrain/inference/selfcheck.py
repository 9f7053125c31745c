"""A model that checks itself on the scan in front of it, and falls back to its classical fill.

A network trained on simulated worlds can meet ground unlike any it saw; nothing tells it so.
The scan itself can: hide a share of its observed cells, fill the map again with the model and
with the model's base fill (the classical fill it corrects), and compare both with the heights
the sensor measured in the hidden cells. The blend ``fill + w (model - fill)`` whose error on
those cells is least has

    w* = sum(d (z - f)) / sum(d^2),   d = model - f on the hidden cells, z the measured heights,

the least-squares weight of the correction, clamped to [0, 1]. The map's full-scan prediction
then keeps ``w*`` of its correction: all of it where the model beats its fill on this scan, none
where it does worse (the map is then the classical fill), in between where it helps a little.
The fill itself is chosen the same way, per map: the smooth fill (the model's base fill or the
plain thin plate, whichever errs less on the hidden cells), moved towards the membrane (Laplace
interpolation: rough ground, noisy scans) by the least-squares share the hidden cells support
(``checked_maps``; the fills come from the generator's ``base_and_plain_fills``). A label-free check of
every map, at the cost of a second pass on the thinned scan.

What the check measures is how the model does next to measured cells: a hidden cell has kept
cells around it. Far from every measured cell (a long shadow, the map's corners beyond the
sensor's range) the model may do better or worse than there: measured per distance band, the
model trained on the mixed world loses to the thin plate next to measured cells of clean scans
and beats it far from them on real terrain. With ``check_reach`` the scan is asked a second
question: hide its outermost observed cells (``outer_cells``: the gap they leave is as wide as
the outer rings' spacing) and weigh the correction there the same way (``w_far``). The map then
keeps ``w = w* (1 - far) + w_far far`` of its correction, ``far = far_share(mask)`` rising from
0 at ``REACH_NEAR`` cells from the nearest observed cell to 1 at ``REACH_FAR``: the near check
next to the scan, the far check away from it. Both groups are hidden in the same pass, so the
reach costs no extra pass of the model.

The outer cells cannot see far either: hidden, each still lies a cell or two from a kept one,
where the net errs most, so ``w_far`` measures the net next to the scan again and refutes
corrections that help in long shadows (docs/transfer.md: on 6 m relief the
shipped net alone scores 0.85 of the best fill, checked with ``w_far`` 1.12). With
``keep_far`` the correction is kept whole far from the scan (``w_far = 1``): the check then
governs where it can measure, next to the scan, and the trained net where nothing can be
measured; the outer cells still weigh the membrane and scale the sigma.

Nor can the check see behind what the scan shows: its hidden cells were all seen by the sensor,
while an obstacle's back, 2-7 cells from the scan, was not, and there the near weight governs a
correction it never measured. With ``keep_shadows`` (``checked_maps``' ``shadow_margin``) the
correction is kept whole in the map's shadows (``shadows.shadow_cells``: unobserved cells whose
fill lies below the sensor's line of sight over the observed cells in front of them), unless the
scan refutes its own horizon: a 2.5-D map of returns under a canopy or past a pole's top puts
cells the sensor saw in shadow, and where ``SHADOW_REFUTED`` of the check's cells fall in the
thinned scan's shadows the correction there is weighed on them instead (``shadow_weight``).

Nor does the check see the corrections that matter most: the net digs a pit or raises an
obstacle's hidden side by decimetres, 2-7 cells from the scan, while on the check's cells (open
ground next to kept cells) its correction is a few centimetres, which set the map's weight
(stop 32: 97 % of the pits' error lies inside them). With ``keep_large`` (``checked_maps``'
``large``) a correction of an obstacle's size (``LARGE_CORRECTION``, either way) is kept whole on
the map's unobserved cells, unless ``LARGE_REFUTED`` or more of the check's random hidden cells
carry one in the thinned scan's map: the scan then measures such corrections, and they keep
their least-squares weight on those cells instead (``kept_weight``). The outer cells do not
count: they leave gaps as wide as the outer rings' spacing, where the net's large corrections
are the far field's, which ``keep_far`` keeps whole whatever they say.
"""

from __future__ import annotations

import torch

from ..models.noise import NOISE_MAD, scan_noise  # noqa: F401  (the check's noise: re-exported)
from .shadows import shadow_cells

#: Share of a map's observed cells hidden for the check (the real-data suite hides 20 % too).
CHECK_SHARE = 0.2
#: Seed of the cells hidden: the same scan gets the same check, so predictions repeat.
CHECK_SEED = 0x5E1F
#: Cells (chessboard distance to the nearest observed cell) up to which the checked weight holds:
#: the reach of the check, whose hidden cells lie next to kept ones.
REACH_NEAR = 2
#: Cells from which the weight measured on the outer cells (``outer_cells``) holds alone.
REACH_FAR = 8
#: The margin of the horizon a scan's shadows lie under (``shadows.horizon``), in the scan's own
#: noises (``scan_noise``): a measured height may lie that far above the ground's.
SHADOW_MARGIN = 3.0
#: The check's cells (hidden, so seen by the sensor) in the thinned scan's shadows from which the
#: horizon counts as refuted on a scan (stop 41: 4 and 16 score alike).
SHADOW_REFUTED = 8
#: A correction at least this large (metres, up or down) is an obstacle's or a pit's: the height at
#: which the scores count a cell as one (``evaluation.metrics.OBSTACLE_THRESHOLD``).
LARGE_CORRECTION = 0.3
#: The check's random hidden cells with a large correction from which the scan measures them
#: (stop 42: 4, 8 and 16 score alike).
LARGE_REFUTED = 8


def hidden_cells(mask: torch.Tensor, share: float = CHECK_SHARE, seed: int = CHECK_SEED) -> torch.Tensor:
    """(B, 1, S, S) bool: about ``share`` of each map's observed cells, drawn from ``seed``.

    One field of the map's size is drawn and laid over every map of the batch, so a map's check
    (and so its checked prediction) is the same whatever batch it comes in and wherever in it."""
    generator = torch.Generator(device="cpu").manual_seed(seed)
    draw = torch.rand(mask.shape[-2:], generator=generator).to(mask.device)
    return (mask > 0) & (draw < share)


def check_cells(mask: torch.Tensor, reach: bool = True) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(hidden, outer, thinned)`` of a check: the random cells (:func:`hidden_cells`, outside the
    outer ones), with ``reach`` the outermost observed cells (:func:`outer_cells`; else none),
    and the mask with both hidden, which one pass of the model answers both checks on."""
    hidden = hidden_cells(mask)
    outer = outer_cells(mask) if reach else torch.zeros_like(hidden)
    hidden = hidden & ~outer
    return hidden, outer, mask * (~(hidden | outer)).to(mask.dtype)


def correction_weight(model: torch.Tensor, fill: torch.Tensor, measured: torch.Tensor, hidden: torch.Tensor) -> torch.Tensor:
    """(B, 1, 1, 1) least-squares weight of ``model - fill`` against ``measured - fill`` on the
    ``hidden`` cells, clamped to [0, 1] (0 where the correction is zero on them)."""
    h = hidden.to(model.dtype)
    d = (model - fill) * h
    num = (d * (measured - fill)).sum(dim=(2, 3), keepdim=True)
    den = (d * d).sum(dim=(2, 3), keepdim=True)
    return torch.where(den > 0, num / den.clamp_min(1e-30), torch.zeros_like(den)).clamp(0.0, 1.0)


#: Tensions of the classical fills the check weighs beside the model's base fill: the thin plate
#: (0: smooth ground, true-scale slopes) and the membrane (1, Laplace interpolation: rough ground
#: and noisy scans, where the thin plate overshoots between neighbouring observations).
CANDIDATE_TENSIONS = (0.0, 1.0)
#: The candidates of a check without the membrane (files packaged before it).
THIN_PLATE_ONLY = (0.0,)


def best_fill(candidates: torch.Tensor, measured: torch.Tensor, hidden: torch.Tensor) -> torch.Tensor:
    """(B,) index of the candidate with the least squared error on each map's hidden cells."""
    h = hidden.to(candidates.dtype)
    errors = (((candidates - measured) * h) ** 2).sum(dim=(2, 3, 4))  # (K, B)
    return errors.argmin(dim=0)


def pick(candidates: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """(B, 1, S, S): candidate ``index[b]`` of each map ``b``."""
    return candidates[index, torch.arange(candidates.shape[1], device=candidates.device)]


class Regimes:
    """Where each weight the check measures holds: ``near`` on the random hidden cells, ``away``
    on the outer cells (``None`` without the reach); a map's weight at a cell is
    ``near (1 - far) + away far`` with ``far = far_share(mask)`` of the map the weight is used on
    (computed once per mask: a check blends the full scan's maps three times and the thinned
    scan's twice; ``masks``, when given, all at once)."""

    def __init__(self, hidden: torch.Tensor, outer: torch.Tensor | None, masks: tuple[torch.Tensor, ...] = ()):
        self.hidden, self.outer = hidden, outer
        self._far: list[tuple[torch.Tensor, torch.Tensor]] = []
        if outer is not None and masks:  # the masks the weights will be used on: their far shares in one batch
            shares = far_share(torch.cat(masks)).split([m.shape[0] for m in masks])
            self._far = list(zip(masks, shares))

    @property
    def checked(self) -> torch.Tensor:
        """(B, 1, S, S) bool: every cell the check hid (the random ones and the outer ones)."""
        return self.hidden if self.outer is None else self.hidden | self.outer

    def measure(self, statistic, *args):
        """``(near, away)``: ``statistic(*args, cells)`` on the hidden cells and on the outer ones."""
        return statistic(*args, self.hidden), None if self.outer is None else statistic(*args, self.outer)

    def weight(self, candidate: torch.Tensor, fill: torch.Tensor, measured: torch.Tensor):
        """``(near, away)``: the least-squares weights of ``candidate - fill`` (``correction_weight``)."""
        return self.measure(correction_weight, candidate, fill, measured)

    def far(self, observed: torch.Tensor) -> torch.Tensor:
        """``far_share(observed)``, remembered for the same mask tensor."""
        for seen, share in self._far:
            if seen is observed:
                return share
        share = far_share(observed)
        self._far.append((observed, share))
        return share

    def at(self, values, observed: torch.Tensor) -> torch.Tensor:
        """A ``(near, away)`` pair as it holds at each cell of a map observed at ``observed``."""
        near, away = values
        if away is None:
            return near
        far = self.far(observed).to(near.dtype)
        return near * (1.0 - far) + away * far

    def apply(self, weights, fill: torch.Tensor, candidate: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
        return fill + self.at(weights, observed) * (candidate - fill)


def checked_maps(fills: torch.Tensor, model: torch.Tensor, scan: torch.Tensor, mask: torch.Tensor, thinned: torch.Tensor,
                 regimes: Regimes, membrane: bool, keep_far: bool, shadow_margin: torch.Tensor | None = None,
                 large: float | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """``(map, thinned map)``, each (N, 1, S, S): the checked map of the full scan and, blended
    the same way, the one of the thinned scan (what the check's cells are scored on).

    ``fills`` (K, 2N, 1, S, S) and ``model`` (2N, 1, S, S) hold the full scans' maps, then the
    thinned scans' (the generator's ``base_and_plain_fills`` of both; the net's maps of both). The classical fill is
    the smooth candidate (the base fill or the thin plate: whichever errs least on the hidden
    cells), and with ``membrane`` (``fills[-1]``) moved towards the membrane by the share the
    check's cells support (``regimes``: near the scan and far from it); the model's correction
    to that fill is then kept in the share the same cells support; with ``keep_far`` (and the
    reach) in full far from the scan, whatever the outer cells say.

    ``shadow_margin`` (2N, 1, 1, 1) metres, both scans' (None: off): the correction is kept
    whole in each map's shadows (:func:`shadow_weight`), the horizon of each observed cell
    lowered by its scan's margin. ``large`` metres (None: off; ``LARGE_CORRECTION``): a
    correction at least that large is kept whole on each map's unobserved cells unless the
    check's random hidden cells measure such corrections (:func:`large_weight`)."""
    n = scan.shape[0]
    fill, fill_thinned = checked_fills(fills, scan, mask, thinned, regimes, membrane)
    w = regimes.weight(model[n:], fill_thinned, scan)
    if keep_far and w[1] is not None:
        w = (w[0], torch.ones_like(w[1]))
    fills_both, models_both, observed_both = (fill, fill_thinned), model.split(n), (mask, thinned)
    kept = [[] for _ in fills_both]  # per map: (cells, the weight they keep at least)
    if shadow_margin is not None:
        shadows = shadow_cells(torch.cat([scan, scan * thinned]), torch.cat(observed_both), torch.cat(fills_both), shadow_margin).split(n)
        keep = shadow_weight(model[n:], fill_thinned, scan, shadows[1] & regimes.checked)
        for cells, out in zip(shadows, kept):
            out.append((cells, keep))
    if large is not None:
        larges = [large_cells(m, f, large) for m, f in zip(models_both, fills_both)]
        keep = large_weight(model[n:], fill_thinned, scan, larges[1] & regimes.hidden)
        for cells, observed, out in zip(larges, observed_both, kept):
            out.append((cells & (observed <= 0), keep))
    maps = []
    for f, m, observed, cells_kept in zip(fills_both, models_both, observed_both, kept):
        weight = regimes.at(w, observed)
        for cells, keep in cells_kept:
            weight = torch.where(cells, torch.maximum(weight, keep), weight)
        maps.append(f + weight * (m - f))
    return maps[0], maps[1]


def kept_weight(model: torch.Tensor, fill: torch.Tensor, measured: torch.Tensor, cells: torch.Tensor, refuted_at: int) -> torch.Tensor:
    """(B, 1, 1, 1) the share of the net's correction a map keeps (at least) where the check
    cannot measure it: all of it, unless ``refuted_at`` or more of the check's ``cells`` are of
    that kind; the scan then measures it, and they keep the least-squares weight of the
    correction on those cells (``correction_weight``)."""
    refuted = cells.sum(dim=(2, 3), keepdim=True) >= refuted_at
    measured_weight = correction_weight(model, fill, measured, cells)
    return torch.where(refuted, measured_weight, torch.ones_like(measured_weight))


def shadow_weight(model: torch.Tensor, fill: torch.Tensor, measured: torch.Tensor, seen_in_shadow: torch.Tensor) -> torch.Tensor:
    """(B, 1, 1, 1) the share of the net's correction a map keeps in its shadows (at least; the
    check's own weight where that is more): all of it, unless ``SHADOW_REFUTED`` or more of the
    check's cells (all seen by the sensor) lie in the thinned scan's shadows. The horizon is then
    refuted on this scan (returns under an overhang: a canopy, a pole, a car's roof), and the
    shadows keep the least-squares weight of the correction on those cells (:func:`kept_weight`)."""
    return kept_weight(model, fill, measured, seen_in_shadow, SHADOW_REFUTED)


def large_cells(model: torch.Tensor, fill: torch.Tensor, large: float) -> torch.Tensor:
    """(B, 1, S, S) bool: cells where the net's correction to ``fill`` is at least ``large`` metres, up or down."""
    return (model - fill).abs() >= large


def large_weight(model: torch.Tensor, fill: torch.Tensor, measured: torch.Tensor, large_hidden: torch.Tensor) -> torch.Tensor:
    """(B, 1, 1, 1) the share of its large corrections a map keeps on its unobserved cells (at
    least): all, unless ``LARGE_REFUTED`` or more of the check's random hidden cells carry one
    (``large_hidden``): they then keep the least-squares weight of the correction on those cells
    (:func:`kept_weight`)."""
    return kept_weight(model, fill, measured, large_hidden, LARGE_REFUTED)


def checked_fills(fills: torch.Tensor, scan: torch.Tensor, mask: torch.Tensor, thinned: torch.Tensor, regimes: Regimes,
                  membrane: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """``(fill, thinned fill)``: the classical fill :func:`checked_maps` weighs the net's
    correction against, of the full scans and of the thinned ones (``fills`` as there): the
    smooth candidate that errs least on the hidden cells, with ``membrane`` moved towards the
    membrane by the share the check's cells support."""
    n = scan.shape[0]
    smooth = fills[:-1] if membrane else fills
    choice = best_fill(smooth[:, n:], scan, regimes.hidden)
    fill, fill_thinned = pick(smooth[:, :n], choice), pick(smooth[:, n:], choice)
    if membrane:
        beta = regimes.weight(fills[-1, n:], fill_thinned, scan)
        fill = regimes.apply(beta, fill, fills[-1, :n], mask)
        fill_thinned = regimes.apply(beta, fill_thinned, fills[-1, n:], thinned)
    return fill, fill_thinned


def far_share(mask: torch.Tensor, near: int = REACH_NEAR, far: int = REACH_FAR) -> torch.Tensor:
    """(B, 1, S, S) in [0, 1]: 0 within ``near`` cells (chessboard distance) of an observed cell,
    1 from ``far`` cells on, linear in the distance between; 1 everywhere on a map with no
    observed cell. The distance comes from ``far`` 3x3 dilations of the observed cells."""
    if not (isinstance(near, int) and isinstance(far, int) and 0 <= near < far):
        raise ValueError(f"far_share: need integers 0 <= near < far, got near={near!r}, far={far!r}")
    reached = (mask > 0).to(torch.float32)
    distance = torch.zeros_like(reached)
    for _ in range(far):
        distance = distance + (1.0 - reached)  # cells not yet reached are one dilation farther
        reached = torch.nn.functional.max_pool2d(reached, 3, stride=1, padding=1)
    return ((distance - near) / (far - near)).clamp(0.0, 1.0).to(mask.dtype if mask.is_floating_point() else torch.float32)


#: Share of each map's observed cells, the farthest from the sensor, hidden for the far check.
OUTER_SHARE = 0.3


def outer_cells(mask: torch.Tensor, share: float = OUTER_SHARE) -> torch.Tensor:
    """(B, 1, S, S) bool: each map's observed cells farthest from its centre (the sensor), the
    outermost ``share`` of them by distance. Hidden, they leave a gap as wide as the spacing of
    the outer rings: what the model's correction does far from the kept cells can be measured
    there, as the random cells of ``hidden_cells`` measure it next to them."""
    size = mask.shape[-1]
    axis = torch.arange(size, device=mask.device, dtype=torch.float32) - 0.5 * (size - 1)
    radius = torch.sqrt(axis[:, None] ** 2 + axis[None, :] ** 2).expand(mask.shape)
    observed = mask > 0
    # per map: the radius below which 1 - share of its observed cells lie (NaN, and no cell, if none)
    cut = torch.nanquantile(torch.where(observed, radius, torch.nan).flatten(1), 1.0 - share, dim=1)
    return observed & (radius > cut.view(-1, 1, 1, 1))


#: Share of the check's hidden cells whose error the calibrated sigma covers (a Gaussian's 1 sigma).
SIGMA_COVERAGE = 0.6827
#: Fewest hidden cells a map needs for its own sigma factor; below it the factor is 1.
SIGMA_MIN_CELLS = 16
#: Standard errors by which the checked errors' quantile must stand above the scan's noise for
#: the check to resolve the map's own error (the quantile's relative standard error is about
#: ``1 / sqrt(cells)`` for Gaussian errors); below that the factor is 1.
SIGMA_RESOLUTION = 2.0


def sigma_factor(predicted: torch.Tensor, sigma: torch.Tensor, measured: torch.Tensor, cells: torch.Tensor,
                 coverage: float = SIGMA_COVERAGE, min_cells: int = SIGMA_MIN_CELLS, noise: torch.Tensor | None = None,
                 resolution: float = SIGMA_RESOLUTION, fallback: float = 1.0) -> torch.Tensor:
    """(B, 1, 1, 1): per map, the factor ``k`` that puts ``coverage`` of the check's ``cells``
    within ``k sigma`` (:func:`resolved_sigma_factor`), or ``fallback`` on a map whose check
    cannot measure its error (too few cells, or errors hidden under the scan's noise): 1 keeps
    the file's own ``sigma_scale``; a Reconstructor passes the factor its file fitted on the
    calibration maps the check could not resolve (``meta["sigma_scale_unresolved"]``)."""
    k, resolved = resolved_sigma_factor(predicted, sigma, measured, cells, coverage, min_cells, noise, resolution)
    return torch.where(resolved.view(-1, 1, 1, 1), k, torch.full_like(k, float(fallback)))


def resolved_sigma_factor(predicted: torch.Tensor, sigma: torch.Tensor, measured: torch.Tensor, cells: torch.Tensor,
                          coverage: float = SIGMA_COVERAGE, min_cells: int = SIGMA_MIN_CELLS, noise: torch.Tensor | None = None,
                          resolution: float = SIGMA_RESOLUTION) -> tuple[torch.Tensor, torch.Tensor]:
    """``(k, resolved)``: per map, ``k`` (B, 1, 1, 1), the factor that puts ``coverage`` of the
    check's ``cells`` within ``k sigma``: the ``coverage`` quantile of ``|predicted - measured| /
    sigma`` there; and ``resolved`` (B,) bool, whether the check measures the map's error at all
    (``k`` is 1 where it does not).
    The check's cells are real measurements the map did not see, so ``k sigma`` means on this
    scan what it says (about 68 % of errors within 1 sigma), whatever ground the model was
    trained on; a quantile, not a mean of squares, so a few wild cells (a wall) do not inflate it.
    Maps with fewer than ``min_cells`` cells are not resolved.

    A measured height errs itself (``noise``, (B, 1, 1, 1) metres: the scan's own noise,
    :func:`scan_noise`), so the checked error ``d = e - n`` of a cell holds the map's error ``e``
    and the measurement's ``n``; sigma is about ``e``, the error against the ground. With
    ``noise`` each cell's ratio is ``sqrt(max(d^2 - noise^2, 0)) / sigma``: for Gaussian ``e`` and
    ``n`` the share of cells under ``k`` is then the share of ``|e| <= k sigma`` (``|d| <= sqrt(k^2
    sigma^2 + noise^2)``), so a noisy scan no longer widens the sigma by its own noise.

    Under the noise the check cannot see the map's error: where the checked errors' ``coverage``
    quantile stands less than ``resolution`` of its own standard errors (``1 / sqrt(cells)`` of
    it) above ``noise``, the map's error is indistinguishable from zero and ``k`` would be 0 or
    near it by chance (on noisy scans a third of the maps, each then with under 40 % of its errors
    within its sigma); such a map is not resolved, as a map with too few cells is not."""
    checked = (predicted - measured).abs()
    error = checked if noise is None else (checked.square() - noise.square()).clamp_min(0.0).sqrt()
    ratio = (error / sigma.clamp_min(1e-6)).float()
    ratio = torch.where(cells, ratio, torch.nan).flatten(1)
    k = torch.nanquantile(ratio, coverage, dim=1)
    count = cells.flatten(1).sum(dim=1)
    resolved = (count >= min_cells) & torch.isfinite(k)
    if noise is not None:
        quantile = torch.nanquantile(torch.where(cells, checked, torch.nan).float().flatten(1), coverage, dim=1)
        floor = noise.flatten().float() * (1.0 + resolution / count.clamp_min(1).float().sqrt())
        resolved &= (noise.flatten() <= 0) | (quantile > floor)
    k = torch.where(resolved, k, torch.ones_like(k))
    return k.view(-1, 1, 1, 1).to(sigma.dtype), resolved
