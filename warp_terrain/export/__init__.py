"""Exports of simulated and reconstructed terrain to other tools: USD stages (``export_usd``),
one generated sample with a model's reconstruction of it (``export_sample``), and a map
reconstructed from a real cloud with its points (``export_reconstruction``)."""

from .scene import export_sample
from .usd import export_reconstruction, export_usd

__all__ = ["export_reconstruction", "export_sample", "export_usd"]
