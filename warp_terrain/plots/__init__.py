"""Figures: previews of simulated samples, the paper's figure kinds, a USD stage drawn, and the
callbacks that let a training run log them."""
