"""The endless stream of training pairs, generated on the fly and never stored.

Batch ``step`` of rank ``rank`` is generated from ``batch_seed(seed, rank, step)``, so any batch
can be regenerated from its coordinates: a resumed run sees exactly the batches an
uninterrupted run would, and ranks and workers never repeat each other. Training seeds lie in
``[0, 2**30)``, validation seeds are ``2**30 + chunk`` and the evaluation test sets start at
``2**31 - 2**24``: the three never meet.

On the CPU a Warp launch is single-threaded and holds the interpreter, so generation runs in
worker processes (``torch.utils.data.DataLoader`` with the ``spawn`` context; worker ``k``
makes steps ``k, k + n, k + 2n, ...`` and the loader interleaves them back into step order).
On CUDA generation stays in the training process, on the device, zero-copy.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from dataclasses import asdict

import torch
from torch.utils.data import DataLoader, IterableDataset, get_worker_info

from ..sim.batch import SimConfig, generate_batch
from ..sim.graph import BatchGraph
from ..sim.projection import cell_offsets
from .disk import DiskPairs
from .scans import ScanMixConfig, ScanPairs
from .seeds import batch_seed, validation_seed


def make_pair(sim: SimConfig, batch_size: int, seed: int, device: str, offsets: bool = False) -> dict[str, torch.Tensor]:
    b = generate_batch(batch_size, sim, seed=seed, device=device)
    return _pair(b, sim, offsets)


def _pair(b, sim: SimConfig, offsets: bool) -> dict[str, torch.Tensor]:
    """A batch's training pair; with ``offsets`` also each cell's returns' mean offset from its
    centre (``offset``, ``(B, 2, S, S)`` metres; ``cell_offsets``), for a model that centres its input."""
    pair = {"scan": b.scan, "mask": b.mask, "target": b.target}
    if offsets:
        pair["offset"] = cell_offsets(b.points, sim.data.map_size, sim.data.map_cell, device=b.points.device)
    return pair


class PairStream(IterableDataset):
    """Batches ``start, start + 1, ...`` (until ``stop``) of one rank's stream. ``capture``:
    each batch replays one recorded batch (``BatchGraph``; the same pairs, bit for bit): a
    yielded pair then shares memory with the next, so it must be used before the next is asked for.
    ``scans``: real scans mixed in (``scans``; each batch then carries ``valid``). ``offsets``:
    each batch also carries ``offset`` (``make_pair``)."""

    def __init__(self, sim: SimConfig, batch_size: int, seed: int, rank: int = 0, start: int = 0, stop: int | None = None, device: str = "cpu",
                 capture: bool = False, scans: ScanMixConfig | None = None, offsets: bool = False):
        super().__init__()
        self.sim, self.batch_size, self.seed, self.rank = sim, batch_size, seed, rank
        self.start, self.stop, self.device, self.capture = start, stop, device, capture
        self.scans = scans if scans is not None and scans.enabled() else None
        self.offsets = offsets
        if offsets and self.scans is not None:
            raise ValueError("offsets: a real scan's pair carries no offsets yet; mix real scans (scans.share) or centre cells, not both")

    def __iter__(self) -> Iterator[dict[str, torch.Tensor]]:
        info = get_worker_info()
        worker, workers = (info.id, info.num_workers) if info is not None else (0, 1)
        step = self.start + worker
        graph = BatchGraph(self.batch_size, self.sim, self.device) if self.capture else None
        data = self.sim.data
        real = ScanPairs(self.scans, data.map_size, data.map_cell, data.fill) if self.scans is not None else None
        while self.stop is None or step < self.stop:
            seed = batch_seed(self.seed, self.rank, step)
            if graph is None:
                pair = make_pair(self.sim, self.batch_size, seed, self.device, self.offsets)
            else:
                pair = _pair(graph(seed), self.sim, self.offsets)
                if info is not None:  # a worker process: sending a tensor moves it to shared memory, off the graph's arrays
                    pair = {k: v.clone() for k, v in pair.items()}
            if real is not None:
                pair = real.mix(pair, seed)
            pair["step"] = torch.tensor(step)
            yield pair
            step += workers


def _init_worker(_worker_id: int) -> None:
    torch.set_num_threads(1)  # the worker unpickled this module, so warp_terrain set Warp's log level already


def training_batches(sim: SimConfig, batch_size: int, seed: int, rank: int, start: int, stop: int, device: str, workers: int, prefetch: int = 4, dataset: str = "",
                     capture: bool = False, scans: ScanMixConfig | None = None, offsets: bool = False):
    """An iterator over the training batches ``start..stop-1`` (dicts of tensors with ``step``).

    ``dataset``: empty for the live stream; else a folder written by ``warp-terrain generate``,
    read in the training process (CPU tensors; ``workers`` unused), cycling over it: batch
    ``step`` is fixed by ``(dataset, seed, rank, step)`` (``DiskPairs.batches``), so resuming
    sees the same batches. Its maps must have ``sim``'s size; a dataset made with another
    config than ``sim`` gets a warning (validation still uses ``sim``). ``capture``: the live
    stream replays a recorded batch per step (``PairStream``). ``scans``: real scans mixed into
    the live stream (``scans``, ``PairStream``). ``offsets``: every batch also carries each
    cell's returns' mean offset (``make_pair``; the live stream only).
    """
    if dataset:
        if offsets:
            raise ValueError(f"offsets: pairs read from disk (dataset {str(dataset)!r}) keep no points to take offsets from")
        return _dataset_batches(sim, str(dataset), batch_size, seed, rank, start, stop)
    on_cuda = device.startswith("cuda")
    if workers == 0 or on_cuda:
        return iter(PairStream(sim, batch_size, seed, rank, start, stop, device, capture, scans, offsets))
    loader = DataLoader(
        PairStream(sim, batch_size, seed, rank, start, stop, "cpu", capture, scans, offsets),
        batch_size=None,
        num_workers=workers,
        multiprocessing_context="spawn",
        worker_init_fn=_init_worker,
        prefetch_factor=prefetch,
        persistent_workers=False,
    )
    return iter(loader)


def _dataset_batches(sim: SimConfig, dataset: str, batch_size: int, seed: int, rank: int, start: int, stop: int):
    try:
        pairs = DiskPairs(dataset)
    except ValueError as err:
        raise ValueError(f"train.dataset={dataset!r}: {err}") from None
    pairs.check_compatible(sim)
    if asdict(pairs.sim) != asdict(sim):
        warnings.warn(f"train.dataset={dataset!r} was generated with a different terrain/lidar/data config than this run's; "
                      "validation uses the run's config", stacklevel=2)
    return pairs.batches(batch_size, seed, rank, start, stop)


def validation_set(sim: SimConfig, size: int, device: str, chunk: int = 16, offsets: bool = False) -> dict[str, torch.Tensor]:
    """The fixed validation pairs: ``size`` samples from the validation seeds (with ``offsets``
    each cell's returns' mean offset too, ``make_pair``)."""
    parts = [make_pair(sim, min(chunk, size - i), validation_seed(i // chunk), device, offsets) for i in range(0, size, chunk)]
    return {k: torch.cat([p[k].clone() for p in parts]) for k in parts[0]}
