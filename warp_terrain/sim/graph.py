"""Fixed-shape batches, recorded once and replayed: ``BatchGraph``.

A training stream asks for the same batch shape again and again with a new seed. ``BatchGraph``
runs the first batch eagerly inside an allocation arena (``sim/arena.py``: every scratch and
output array made once), then, on CUDA, captures the launches of one batch (terrain -> scans ->
maps) as a CUDA graph (``wp.ScopedCapture``). Every later call writes the seed into the device
array all kernels read and launches the graph: no allocation, no host work, no host sync, one
launch for the batch. On the CPU (or with ``capture=False``) later calls replay the same
launches on the same arrays without a graph.

The batch it returns shares memory with those arrays, so the next call overwrites it (as a
CUDA graph's static outputs do): consume or copy a batch before asking for the next. Calls are
ordered on torch's current stream, like ``generate_batch``.
"""

from __future__ import annotations

import torch
import warp as wp

from ..core.checks import require
from .arena import Arena, Seed
from .batch import Batch, as_batch, as_sim_config, run_stages, terrain_size
from .device import resolve_device, torch_stream
from .memory import check_batch_fits
from .terrain import scratch_bytes


class BatchGraph:
    """``BatchGraph(batch, cfg, device)(seed)`` equals ``generate_batch(batch, cfg, seed, device)``
    bit for bit, replayed from its first call (see the module's docstring).

    ``capture``: record a CUDA graph (default: on CUDA); False replays the launches one by one.
    The world must be fixed: no domain randomisation and fBm terrain (DEM windows are cut on the
    host per seed).
    """

    def __init__(self, batch: int, cfg=None, device=None, capture: bool | None = None):
        require(isinstance(batch, int) and not isinstance(batch, bool) and batch >= 1, "batch", batch, "must be an integer >= 1")
        sim = as_sim_config(cfg)
        require(not sim.data.randomize.enabled, "data.randomize.enabled", True,
                "draws a new world per batch on the host: a replayed batch needs a fixed one (turn it off)")
        require(sim.terrain.source == "fbm", "terrain.source", sim.terrain.source,
                "must be fbm: DEM windows are cut on the host for each seed, which a replayed batch cannot do")
        device = resolve_device(device)
        cuda = wp.get_device(device).is_cuda
        capture = cuda if capture is None else bool(capture)
        require(not capture or cuda, "capture", capture, f"needs a CUDA device, got {device}")
        check_batch_fits(batch, terrain_size(sim), sim.lidar.num_rays, sim.data.map_size, device, scratch_bytes(sim.terrain))
        self.batch, self.sim, self.device, self.capture = batch, sim, device, capture
        self.seed = Seed(0, wp.zeros(1, dtype=int, device=device))
        self.arena = Arena()
        self.graph = None
        self._out: Batch | None = None

    @property
    def replays(self) -> bool:
        """Whether the next call replays (the first one has run)."""
        return self.arena.recorded

    def _run(self) -> dict[str, wp.array]:
        with self.arena.run():
            return run_stages(self.batch, self.sim, self.seed, self.device)

    def __call__(self, seed: int = 0) -> Batch:
        require(isinstance(seed, int) and not isinstance(seed, bool), "seed", seed, "must be an integer")
        value = int(seed) & 0x7FFFFFFF
        self.seed.value = value
        with torch_stream(self.device):
            self.seed.array.fill_(value)  # the one write per batch; the graph reads it
            if self._out is None:  # the first batch: eager, recording every array
                self._out = as_batch(self._run())
                if self.capture:
                    self._record_graph()
            elif self.graph is not None:
                wp.capture_launch(self.graph)
            else:
                self._run()
        return self._out

    def _record_graph(self) -> None:
        """Capture one replay of the launches (not run now: the arrays already hold the first
        batch). Captured on a side stream (CUDA cannot capture torch's legacy default stream);
        the graph is then launched on whatever stream is current at each call."""
        current = torch.cuda.current_stream(torch.device(self.device))
        side = torch.cuda.Stream(torch.device(self.device))
        side.wait_stream(current)
        stream = wp.stream_from_torch(side)
        # the first, eager batch loaded every module the launches use: load nothing else here
        with wp.ScopedStream(stream), wp.ScopedCapture(device=self.device, stream=stream, force_module_load=False) as capture:
            self._run()
        current.wait_stream(side)
        self.graph = capture.graph
