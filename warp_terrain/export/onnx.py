"""ONNX export of a generator, checked against torch with ONNX Runtime."""

from __future__ import annotations

import os
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from ..atomic import atomic_path


def export_onnx(generator: torch.nn.Module, path: str | os.PathLike, in_channels: int, map_size: int = 121, opset: int = 17) -> Path:
    """Write ``generator`` as ONNX (input ``condition`` (B, C, S, S) with a dynamic batch,
    output ``height`` (B, 1, S, S)), atomically."""
    path = Path(path)
    if path.suffix.lower() != ".onnx":
        raise ValueError(f"{str(path)!r}: the output must end in .onnx")
    if not path.parent.is_dir():
        raise ValueError(f"{str(path)!r}: the output folder {str(path.parent)!r} does not exist")
    generator = generator.eval().cpu()
    example = torch.zeros(1, in_channels, map_size, map_size)
    with atomic_path(path) as tmp, warnings.catch_warnings():
        # the spatial size is fixed at export (the nets' padding is computed from it)
        warnings.simplefilter("ignore", torch.jit.TracerWarning)
        torch.onnx.export(
            generator,
            (example,),
            str(tmp),
            input_names=["condition"],
            output_names=["height"],
            dynamic_axes={"condition": {0: "batch"}, "height": {0: "batch"}},
            opset_version=opset,
            dynamo=False,
        )
    return path


def check_onnx(generator: torch.nn.Module, path: str | os.PathLike, condition: torch.Tensor, repeats: int = 20) -> dict:
    """Max |torch - onnxruntime| on ``condition`` and the median latency of each (ms)."""
    import onnxruntime as ort

    generator = generator.eval().cpu()
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    x = condition.float().cpu()
    with torch.no_grad():
        expected = generator(x).numpy()
    got = session.run(["height"], {"condition": x.numpy()})[0]

    def median_ms(fn) -> float:
        fn()
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t)
        return float(np.median(times) * 1e3)

    with torch.no_grad():
        torch_ms = median_ms(lambda: generator(x))
    onnx_ms = median_ms(lambda: session.run(["height"], {"condition": x.numpy()}))
    return {"max_abs_diff": float(np.abs(expected - got).max()), "torch_ms": torch_ms, "onnxruntime_ms": onnx_ms, "batch": int(x.shape[0])}
