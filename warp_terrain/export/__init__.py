"""Exports of simulated and reconstructed terrain to other tools: USD stages."""

from .usd import export_usd

__all__ = ["export_usd"]
