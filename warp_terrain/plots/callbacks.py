"""Figures a training run logs through the loop's callbacks (the loop never imports plots)."""

from __future__ import annotations

from ..data.seeds import FIGURE_SEED
from ..inference.predictor import model_predictor
from .paper import prediction_figure, reconstruction_3d_figure


class PaperFigures:
    """At the end of a run: the paper's model figures (Figs. 5 and 6) of the final model, into TensorBoard."""

    def on_finish(self, writer, model, cfg, device: str, step: int) -> None:
        predictor = model_predictor(model, cfg.model.in_channels)
        sim, seed = cfg.sim(), FIGURE_SEED
        writer.add_figure("figures/fig5_reconstruction_3d", reconstruction_3d_figure(predictor, sim, seed=seed, device=device), step)
        writer.add_figure("figures/fig6_input_prediction_truth", prediction_figure(predictor, sim, seed=seed, device=device), step)
