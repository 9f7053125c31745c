"""Exports of simulated and reconstructed terrain to other tools: USD stages (``export_usd``),
and one generated sample with a model's reconstruction of it (``export_sample``)."""

from .scene import export_sample
from .usd import export_usd

__all__ = ["export_sample", "export_usd"]
