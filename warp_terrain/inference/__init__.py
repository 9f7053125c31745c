"""Using a trained model: ``Reconstructor`` (point cloud in, map out), the one ``Predictor``
type, point-cloud readers and ONNX export."""

from .predictor import Predictor, load_predictor, model_predictor
from .reconstructor import Reconstructor, pretrained_path

__all__ = ["Predictor", "Reconstructor", "load_predictor", "model_predictor", "pretrained_path"]
