"""Probe: an ensemble of independently trained generators (different seeds of one recipe) inside
one checked ``Reconstructor``, scored on the real suite and the synthetic settings.

usage: python tools/probes/ensemble.py [--fills-cache FILE] NAME=MODEL[+MODEL...] ...
  MODEL as ``tools/real_ablation.py`` takes it (a checkpoint, a Reconstructor file, or `shipped`);
  several joined by ``+`` are one ensemble: the members share the first one's base fill and its
  file's check settings; the height is the members' mean and the variance the mixture's (the
  members' mean variance plus the variance of their heights), so the self-check weighs the
  ensemble's correction as it weighs one net's. NAME flags as in real_ablation.

A seed moves a family's score by up to ~4 points (README, S1): averaging members removes that
variance, at one more pass of the net per member.
"""

import os
import sys

import torch
from torch import nn

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import real_ablation  # noqa: E402

from warp_terrain.inference.reconstructor import Reconstructor  # noqa: E402
from warp_terrain.models.uncertainty import split_output  # noqa: E402


class Ensemble(nn.Module):
    """Generators with the same base fill -> the mean height and the mixture's log-variance."""

    def __init__(self, members: list[nn.Module], uncertainty: bool):
        super().__init__()
        self.members = nn.ModuleList(members)
        self.uncertainty = uncertainty

    def base_fill(self, scan, mask):
        return self.members[0].base_fill(scan, mask)

    def base_and_plain_fills(self, *args, **kwargs):
        return self.members[0].base_and_plain_fills(*args, **kwargs)

    def forward(self, condition, fill=None):
        fill = self.base_fill(condition[:, :1], condition[:, 1:2]) if fill is None else fill
        outs = [split_output(m(condition, fill=fill), self.uncertainty) for m in self.members]
        heights = torch.stack([h for h, _ in outs])
        height = heights.mean(dim=0)
        if not self.uncertainty:
            return height
        variance = torch.stack([v.exp() for _, v in outs]).mean(dim=0) + heights.var(dim=0, unbiased=False)
        return torch.cat([height, variance.log()], dim=1)


def ensemble(path: str) -> tuple[Ensemble, object, dict]:
    """``(generator, model config, meta)`` of ``MODEL+MODEL...``: the first member's config and meta."""
    recs = [Reconstructor.load(None if p == "shipped" else p, device="cpu") for p in path.split("+")]
    first = recs[0]
    for rec in recs[1:]:
        c, f = rec.model_config, first.model_config
        if (c.base_fill, c.height_reference, c.uncertainty) != (f.base_fill, f.height_reference, f.uncertainty):
            raise ValueError(f"ensemble members differ in base fill, reference or uncertainty: {path}")
    return Ensemble([r.generator for r in recs], first.has_uncertainty), first.model_config, first.meta


def main() -> None:
    plain_load = Reconstructor.load

    def load(path=None, device=None, **kwargs):
        if path is not None and "+" in str(path):
            return Reconstructor(*ensemble(str(path)), device, **kwargs)
        return plain_load(path, device=device, **kwargs)

    Reconstructor.load = staticmethod(load)
    real_ablation.main()


if __name__ == "__main__":
    main()
