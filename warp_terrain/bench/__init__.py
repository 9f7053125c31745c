"""Reproducible benchmarks: fixed, seeded workloads timed on one device, with anchors.

- :mod:`.harness`: the seed, device synchronisation, timed repeats after one warm-up call
  (median reported), torch thread scoping, :func:`environment` and the result record.
- :mod:`.noise` (NOISE): fBm heightfields (64 of 121x121, 5 octaves) -> ``samples_per_s``.
- :mod:`.rays` (RAYS): an HDL-64E-like scan (64 x 2048 rays) over a 512x512, 0.1 m heightfield
  -> ``rays_per_s`` and the hit fraction.
- :mod:`.stream` (STREAM): ``generate_batch(B, SimConfig())`` -> ``pairs_per_s``, with a
  per-stage breakdown (terrain, ray cast, projection + ground truth).
- :mod:`.loader`: the training stream in-process and with generator worker processes.
- :mod:`.train` (TRAIN): the paper's model -> ``images_per_s`` of optimiser steps, with data
  wait, channels_last and ``torch.compile`` (run by :mod:`.compiled_child` in a child process).
- :mod:`.infer` (INFER): points -> map latency of the shipped ``Reconstructor``, its network
  under torch and ONNX Runtime.
- :mod:`.anchors`: the optional anchors, pyfastnoiselite for NOISE and Open3D's
  ``RaycastingScene`` for RAYS (with the 1 mm agreement of the two ray casters); a missing one
  is reported (``available: false`` and the reason), never raised.
- :mod:`.registry`: :data:`BENCHMARKS`, :func:`parse_only`, :func:`run_benchmarks` (a selection,
  with the environment).
- :mod:`.table`: :func:`format_table` renders a run for people.
- :mod:`.gpucheck`: ``warp-terrain gpu-check``, the check of a machine's CPU and CUDA device
  (compile, consistency, throughput) as a PASS/FAIL/SKIP table under a hard time limit.
"""

from .anchors import compare_hits, heightfield_triangles, open3d_hits
from .harness import environment
from .infer import bench_infer
from .loader import bench_loader
from .noise import bench_noise
from .rays import bench_rays
from .registry import BENCHMARKS, parse_only, run_benchmarks
from .stream import bench_stream
from .table import format_table
from .train import bench_train

__all__ = [
    "BENCHMARKS",
    "bench_infer",
    "bench_loader",
    "bench_noise",
    "bench_rays",
    "bench_stream",
    "bench_train",
    "compare_hits",
    "environment",
    "format_table",
    "heightfield_triangles",
    "open3d_hits",
    "parse_only",
    "run_benchmarks",
]
