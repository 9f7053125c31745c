"""A classical fill inside the network: push-pull interpolation, and a generator that corrects it.

``push_pull_fill`` fills the unobserved cells of a height map from the observed ones with a
normalised-convolution pyramid (the "push-pull" of Gortler et al., 1996): observed heights and
their weights are averaged down to 1x1, then each level's holes are filled from the level above,
bilinearly upsampled. Observed cells keep their heights exactly. It is a few pooling and
interpolation ops: differentiable, batched on the device, and exportable to ONNX.

``FillResidualGenerator`` wraps any generator so it predicts a correction to that fill: its
input is the fill and the mask (heights relative to the mean observed height, so the net does
not have to learn where the sensor is mounted), and its output is ``fill + correction``. Before
training it already is the classical fill; training only has to learn what the fill gets wrong.
With ``height_scale_min > 0`` the heights it sees are also divided by the map's spread of
observed heights (:func:`observed_spread`) and its correction multiplied by it: the net then
works in units of the map's own relief, so a 5 cm meadow and a 4 m hillside look alike to it.
A second output channel (``model.uncertainty``: a log-variance) is passed on, shifted by
``2 log s`` so that it too is in metres squared. With ``screening > 0`` the net also sees a
second fill (:func:`screened_fill`: the thin plate screened towards the mean observed height),
so it can learn which far field a map wants: the slope run on, or a return to the mean.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .biharmonic import biharmonic_fill, biharmonic_fills
from .noise import scan_noise

#: base fills a ``FillResidualGenerator`` can correct
BASE_FILLS = ("push_pull", "biharmonic", "plane_biharmonic")
#: what the net's heights are taken relative to: the mean observed height, or the observed cells'
#: least-squares plane (a tilted window then looks level to the net)
HEIGHT_REFERENCES = ("mean", "plane")


def push_pull_fill(height: torch.Tensor, mask: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """(B, 1, H, W) heights and 0/1 mask -> the same heights with unobserved cells filled.

    A map with no observed cell comes back as zeros.
    """
    values = [height * mask]
    weights = [mask]
    while values[-1].shape[-1] > 1 or values[-1].shape[-2] > 1:
        values.append(F.avg_pool2d(values[-1], 2, ceil_mode=True))
        weights.append(F.avg_pool2d(weights[-1], 2, ceil_mode=True))
    estimate = values[-1] / weights[-1].clamp_min(eps)
    for v, w in zip(reversed(values[:-1]), reversed(weights[:-1])):
        coarse = F.interpolate(estimate, size=v.shape[-2:], mode="bilinear", align_corners=False)
        trust = (w * 4.0).clamp(max=1.0)  # a quarter-observed block is trusted fully
        estimate = trust * (v / w.clamp_min(eps)) + (1.0 - trust) * coarse
    return estimate


def screened_fill(height: torch.Tensor, mask: torch.Tensor, screening: float) -> torch.Tensor:
    """The thin plate screened by ``screening`` (k, 1 / cells) about the mean observed height: it
    keeps the observed cells and returns to their mean within about ``1 / k`` cells of the scan
    (:func:`biharmonic_fill`; no gradient: it has no parameters)."""
    with torch.no_grad():
        mean = mean_observed(height, mask)
        return biharmonic_fill(height - mean, mask, screening=screening) + mean


def mean_observed(height: torch.Tensor, mask: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """(B, 1, 1, 1) mean height of each map's observed cells (0 where none)."""
    return (height * mask).sum(dim=(2, 3), keepdim=True) / mask.sum(dim=(2, 3), keepdim=True).clamp_min(eps)


def observed_spread(height: torch.Tensor, mask: torch.Tensor, reference: torch.Tensor, floor: float) -> torch.Tensor:
    """(B, 1, 1, 1) root-mean-square of each map's observed heights about ``reference`` (a
    (B, 1, 1, 1) height or a (B, 1, H, W) surface),
    at least ``floor`` (also for maps with no observed cell)."""
    var = (((height - reference) ** 2) * mask).sum(dim=(2, 3), keepdim=True) / mask.sum(dim=(2, 3), keepdim=True).clamp_min(1.0)
    return var.sqrt().clamp_min(floor)


def observed_plane(height: torch.Tensor, mask: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """(B, 1, H, W): each map's least-squares plane through its observed cells (in cell units),
    the mean observed height where the cells do not fix a plane (fewer than three, or in a line).

    Closed form (centred 2x2 normal equations, Cramer's rule): elementwise ops only, so it runs
    batched on any device and exports to ONNX."""
    h, w = height.shape[-2:]
    rows = torch.arange(h, dtype=height.dtype, device=height.device).view(1, 1, h, 1).expand(1, 1, h, w)
    cols = torch.arange(w, dtype=height.dtype, device=height.device).view(1, 1, 1, w).expand(1, 1, h, w)
    count = mask.sum(dim=(2, 3), keepdim=True).clamp_min(eps)

    def mean(v):
        return (v * mask).sum(dim=(2, 3), keepdim=True) / count

    mean_z, mean_r, mean_c = mean(height), mean(rows), mean(cols)
    dz, dr, dc = height - mean_z, rows - mean_r, cols - mean_c
    srr, scc, src = mean(dr * dr), mean(dc * dc), mean(dr * dc)
    szr, szc = mean(dz * dr), mean(dz * dc)
    det = srr * scc - src * src
    usable = det > eps * (srr + scc).clamp_min(eps) ** 2  # not a line or a point
    safe = torch.where(usable, det, torch.ones_like(det))
    a = torch.where(usable, (szr * scc - szc * src) / safe, torch.zeros_like(det))
    b = torch.where(usable, (szc * srr - szr * src) / safe, torch.zeros_like(det))
    return mean_z + a * dr + b * dc


class FillResidualGenerator(nn.Module):
    """condition (B, 2, H, W) = (scan, mask) -> fill + s * net((fill - reference) / s, mask).

    - ``base``: the classical fill corrected: ``"push_pull"`` (:func:`push_pull_fill`) or
      ``"biharmonic"`` (:func:`biharmonic_fill`, the thin plate), or ``"plane_biharmonic"`` (the
      thin plate of the heights about the observed cells' plane, plus that plane: a slope runs
      on into the holes, and with ``reference="plane"`` the whole model moves by exactly any
      plane added to the scan);
    - ``reference``: ``"mean"`` (the mean observed height) or ``"plane"`` (the observed cells'
      least-squares plane, :func:`observed_plane`);
    - s is 1, or the spread of the observed heights about the reference (>= ``height_scale_min``
      metres) if that is > 0;
    - ``observed_bound`` > 0 (m): on observed cells the correction is at most this big
      (``bound * tanh(c / bound)``), so the map keeps what the sensor saw to within its error;
      with ``noise_bound`` > 0 the bound of each map is at least that many times its scan's own
      noise (:func:`~warp_terrain.models.noise.scan_noise`): a scan whose cells err by 20 cm may
      be denoised, a clean one keeps ``observed_bound``;
    - ``screening`` > 0 (1 / cells): a third input channel, :func:`screened_fill` about the same
      reference and scale as the base fill (appended last, so a net trained without it widens
      by a zero column to exactly the same model).

    Output channels after the first (a log-variance) come back as ``net + 2 log s``."""

    def __init__(self, net: nn.Module, height_scale_min: float = 0.0, base: str = "push_pull", reference: str = "mean",
                 observed_bound: float = 0.0, screening: float = 0.0, noise_bound: float = 0.0):
        super().__init__()
        if base not in BASE_FILLS:
            raise ValueError(f"base fill {base!r}: expected one of {', '.join(BASE_FILLS)}")
        if reference not in HEIGHT_REFERENCES:
            raise ValueError(f"height reference {reference!r}: expected one of {', '.join(HEIGHT_REFERENCES)}")
        self.net = net
        self.height_scale_min = float(height_scale_min)
        if not 0.0 <= screening < float("inf"):
            raise ValueError(f"screening must be a finite number >= 0 (1 / cells), got {screening}")
        self.base, self.reference, self.observed_bound = base, reference, float(observed_bound)
        self.screening = float(screening)
        if not 0.0 <= noise_bound < float("inf"):
            raise ValueError(f"noise_bound must be a finite number >= 0 (times the scan's noise), got {noise_bound}")
        if noise_bound > 0 and self.observed_bound <= 0:
            raise ValueError("noise_bound: needs observed_bound > 0 (the bound it may widen)")
        self.noise_bound = float(noise_bound)

    def base_fill(self, scan: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """The classical fill the net corrects (no gradient: it has no parameters)."""
        return self.base_and_plain_fills(scan, mask)[0]

    def base_and_plain_fills(self, scan: torch.Tensor, mask: torch.Tensor, tensions: tuple[float, ...] = (),
                             count: int | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """``(base, plain)``: the base fill (B, 1, H, W) of every map, and the plain fills
        (len(tensions), count, 1, H, W) of the first ``count`` maps (all if None): the heights as
        they are filled under each of ``tensions`` (:func:`biharmonic_fill`; the fills the
        self-check weighs). With a thin-plate base all of them are one batched solve
        (:func:`biharmonic_fills`)."""
        count = scan.shape[0] if count is None else int(count)
        with torch.no_grad():
            plain = [(scan[:count], mask[:count], float(t)) for t in tensions]
            if self.base == "push_pull":
                base, fills = push_pull_fill(scan, mask), biharmonic_fills(plain)
            elif self.base == "biharmonic":
                base, *fills = biharmonic_fills([(scan, mask, 0.0), *plain])
            else:  # plane_biharmonic
                plane = observed_plane(scan, mask)
                base, *fills = biharmonic_fills([(scan - plane, mask, 0.0), *plain])
                base = base + plane
            return base, torch.stack(fills) if fills else scan.new_zeros(0, count, *scan.shape[1:])

    def forward(self, condition: torch.Tensor, fill: torch.Tensor | None = None, noise: torch.Tensor | None = None) -> torch.Tensor:
        """``fill``: the base fill of this condition if the caller has it already (the
        Reconstructor computes it once for the eight orientations and the self-check); ``noise``
        likewise, (B, 1, 1, 1) its scans' :func:`~warp_terrain.models.noise.scan_noise` (the same
        in every orientation), used with ``noise_bound``."""
        scan, mask = condition[:, :1], condition[:, 1:2]
        fill = self.base_fill(scan, mask) if fill is None else fill
        reference = height_reference(scan, mask, self.reference)
        if self.height_scale_min > 0:
            scale = observed_spread(scan, mask, reference, self.height_scale_min)
        else:  # metres: dividing and multiplying by exactly 1 changes no bit
            scale = torch.ones_like(reference[:, :, :1, :1])
        inputs = [(fill - reference) / scale, mask]
        if self.screening > 0:
            inputs.append((screened_fill(scan, mask, self.screening) - reference) / scale)
        out = self.net(torch.cat(inputs, dim=1))
        correction = scale * out[:, :1]
        if self.observed_bound > 0:
            bounded = self.observed_bound * torch.tanh(correction / self.observed_bound)
            if self.noise_bound > 0:  # per map: at least noise_bound times the scan's own noise
                noise = scan_noise(scan, mask) if noise is None else noise
                bound = (self.noise_bound * noise).clamp_min(self.observed_bound)
                bounded = bound * torch.tanh(correction / bound)
            correction = mask * bounded + (1.0 - mask) * correction
        height = fill + correction
        return height if out.shape[1] == 1 else torch.cat([height, out[:, 1:] + 2.0 * torch.log(scale)], dim=1)


def widen_to_screened_input(state: dict[str, torch.Tensor], generator: FillResidualGenerator) -> dict[str, torch.Tensor]:
    """A state dict of the same generator without the screened input -> one for ``generator``
    (with it): every input convolution gets a zero column for the last input channel, so the
    widened model predicts exactly what the narrow one did until training moves that column."""
    target = generator.state_dict()
    unknown = sorted(set(state) - set(target))
    if unknown:
        raise ValueError(f"not in the widened generator: {', '.join(unknown)}")
    out = {}
    for key, value in state.items():
        want = target[key].shape
        if value.shape != want:
            if not (value.dim() == 4 and value.shape[0] == want[0] and value.shape[2:] == want[2:] and want[1] == value.shape[1] + 1):
                raise ValueError(f"{key}: shape {tuple(value.shape)} cannot widen to {tuple(want)} by one input channel")
            value = torch.cat([value, value.new_zeros(value.shape[0], 1, *value.shape[2:])], dim=1)
        out[key] = value
    return out


def unobserved_weight_map(mask: torch.Tensor, unobserved_weight: float) -> torch.Tensor:
    """Per-cell loss weights: 1 on observed cells, ``unobserved_weight`` elsewhere, mean 1."""
    weight = mask + unobserved_weight * (1.0 - mask)
    return weight / weight.mean(dim=(1, 2, 3), keepdim=True)


def height_reference(scan: torch.Tensor, mask: torch.Tensor, reference: str) -> torch.Tensor:
    """The surface heights are taken relative to: ``"mean"`` (B, 1, 1, 1) or ``"plane"`` (B, 1, H, W)."""
    if reference not in HEIGHT_REFERENCES:
        raise ValueError(f"height reference {reference!r}: expected one of {', '.join(HEIGHT_REFERENCES)}")
    return observed_plane(scan, mask) if reference == "plane" else mean_observed(scan, mask)


def loss_weight_map(scan: torch.Tensor, mask: torch.Tensor, unobserved_weight: float = 1.0, relief_floor: float = 0.0,
                    reference: str = "mean") -> torch.Tensor | None:
    """Per-cell weights of the L1 (and NLL) terms, or None for the plain mean: unobserved cells
    weighted by ``unobserved_weight`` (:func:`unobserved_weight_map`), and with
    ``relief_floor > 0`` each map by ``1 / observed_spread`` about the ``reference`` surface
    (at least ``relief_floor``), normalised so the batch's mean weight is 1."""
    weight = unobserved_weight_map(mask, unobserved_weight) if unobserved_weight != 1.0 else None
    if relief_floor <= 0:
        return weight
    inverse = 1.0 / observed_spread(scan, mask, height_reference(scan, mask, reference), relief_floor)
    inverse = inverse / inverse.mean()
    return inverse.expand_as(mask) if weight is None else weight * inverse


#: How a map's base-fill error is summed up for its loss weight: the mean over its unobserved cells,
#: or their median (a few deep cells, the inside of a pit, do not make a map count less)
FILL_ERROR_STATISTICS = ("mean", "median")


def fill_relative_weight(base: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, floor: float, power: int = 1,
                         valid: torch.Tensor | None = None, statistic: str = "mean") -> torch.Tensor:
    """(B, 1, 1, 1) per-map loss weights ``1 / e`` normalised to a batch mean of 1, where ``e``
    is the base fill's mean absolute error on the map's unobserved cells (at least ``floor``
    metres), or with ``power=2`` (a squared-error loss) its mean squared error there (at least
    ``floor ** 2``): the loss then counts each map's error relative to what the classical fill
    leaves, so a map the fill already gets nearly right weighs as much as a hard one, and a
    correction that helps the hard maps cannot buy that with damage to the easy ones. ``valid``
    (B, 1, H, W), where given: the cells whose target is known (a real scan's returns); ``e`` is
    then taken over the unobserved cells among them. With ``statistic="median"`` ``e`` is the
    median of those cells' errors (the lower middle value of an even count) instead of their mean:
    a map whose fill is close everywhere but in a few cells (pits and ditches the sensor cannot see
    into, a few per cent of the unobserved cells, err by metres) keeps the weight of its ground,
    and those cells the weight of their error, where the mean would count the whole map a few
    times less. A map without unobserved cells: ``e`` = the floor."""
    if statistic not in FILL_ERROR_STATISTICS:
        raise ValueError(f"fill error statistic {statistic!r}: expected one of {', '.join(FILL_ERROR_STATISTICS)}")
    unobserved = 1.0 - mask if valid is None else (1.0 - mask) * valid
    error = (base - target).abs() ** power
    if statistic == "median":
        cells = torch.where(unobserved > 0, error, torch.nan).flatten(1)
        error = torch.nanmedian(cells, dim=1).values.nan_to_num(0.0).view(-1, 1, 1, 1)
    else:
        error = (error * unobserved).sum(dim=(2, 3), keepdim=True) / unobserved.sum(dim=(2, 3), keepdim=True).clamp_min(1.0)
    inverse = 1.0 / error.clamp_min(floor**power)
    return inverse / inverse.mean()
