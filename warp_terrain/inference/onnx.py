"""ONNX export of a generator, checked against torch with ONNX Runtime."""

from __future__ import annotations

import os
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from ..core.atomic import atomic_path
from ..core.geometry import MAP_SIZE
from ..models.uncertainty import split_output

#: How far ONNX Runtime's outputs may lie from torch's: ``height`` in metres, ``log_variance`` in
#: log m^2 (0.01 moves a sigma by 0.5 %). A fill-residual model solves its base fill by a fixed
#: count of float32 conjugate-gradient steps (``models/biharmonic.py``); where a map's solve has
#: not settled, the two runtimes' roundings (the same ops, summed in another order) lead it to
#: other points of the same unfinished path. Measured on the shipped file, 68 maps of the
#: default stream: heights apart by 7e-7 m at the median map and 3.9e-4 m at the most,
#: log-variances by 1.5e-3 at the most; torch's own float32 thin plate lies up to 9.6e-4 m from
#: its float64 solve. A millimetre is well under any LIDAR's range noise.
PARITY_TOLERANCE = {"height": 1e-3, "log_variance": 1e-2}


class SplitOutputs(torch.nn.Module):
    """A generator whose outputs are named: ``height`` and, with an uncertainty head, the
    clamped ``log_variance`` (log m^2) as a second output."""

    def __init__(self, generator: torch.nn.Module, uncertainty: bool):
        super().__init__()
        self.generator = generator
        self.uncertainty = uncertainty

    @property
    def output_names(self) -> list[str]:
        return ["height", "log_variance"] if self.uncertainty else ["height"]

    def forward(self, condition: torch.Tensor):
        height, log_variance = split_output(self.generator(condition), self.uncertainty)
        return (height, log_variance) if self.uncertainty else height


def export_onnx(
    generator: torch.nn.Module, path: str | os.PathLike, in_channels: int, map_size: int = MAP_SIZE, opset: int = 17, uncertainty: bool = False
) -> Path:
    """Write ``generator`` as ONNX (input ``condition`` (B, C, S, S) with a dynamic batch,
    output ``height`` (B, 1, S, S), and ``log_variance`` (B, 1, S, S) with ``uncertainty``),
    atomically."""
    path = Path(path)
    if path.suffix.lower() != ".onnx":
        raise ValueError(f"{str(path)!r}: the output must end in .onnx")
    if not path.parent.is_dir():
        raise ValueError(f"{str(path)!r}: the output folder {str(path.parent)!r} does not exist")
    model = SplitOutputs(generator.eval().cpu(), uncertainty)
    example = torch.zeros(1, in_channels, map_size, map_size)
    with atomic_path(path) as tmp, warnings.catch_warnings():
        # the spatial size is fixed at export (the nets' padding is computed from it)
        warnings.simplefilter("ignore", torch.jit.TracerWarning)
        torch.onnx.export(
            model,
            (example,),
            str(tmp),
            input_names=["condition"],
            output_names=model.output_names,
            dynamic_axes={name: {0: "batch"} for name in ["condition", *model.output_names]},
            opset_version=opset,
            dynamo=False,
        )
    return path


def check_onnx(generator: torch.nn.Module, path: str | os.PathLike, condition: torch.Tensor, repeats: int = 20, uncertainty: bool = False) -> dict:
    """|torch - onnxruntime| on ``condition``: the largest per output (``max_abs_diff_by_output``)
    and over all of them (``max_abs_diff``), the outputs beyond :data:`PARITY_TOLERANCE`
    (``beyond_tolerance``, empty when the export holds), and the median latency of each (ms)."""
    import onnxruntime as ort

    model = SplitOutputs(generator.eval().cpu(), uncertainty)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    x = condition.float().cpu()
    with torch.no_grad():
        expected = model(x)
    expected = [t.numpy() for t in (expected if uncertainty else (expected,))]
    got = session.run(model.output_names, {"condition": x.numpy()})

    def median_ms(fn) -> float:
        fn()
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t)
        return float(np.median(times) * 1e3)

    with torch.no_grad():
        torch_ms = median_ms(lambda: model(x))
    onnx_ms = median_ms(lambda: session.run(model.output_names, {"condition": x.numpy()}))
    by_output = {name: float(np.abs(e - g).max()) for name, e, g in zip(model.output_names, expected, got)}
    beyond = [name for name, diff in by_output.items() if not diff <= PARITY_TOLERANCE[name]]
    return {"max_abs_diff": max(by_output.values()), "max_abs_diff_by_output": by_output, "beyond_tolerance": beyond,
            "torch_ms": torch_ms, "onnxruntime_ms": onnx_ms, "batch": int(x.shape[0]), "outputs": model.output_names}
