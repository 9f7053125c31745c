"""Fixed, seeded datasets on disk: sharded ``.npz`` files and a ``manifest.json``.

For people who want a frozen benchmark instead of the endless stream. A dataset folder holds::

    manifest.json         what it is: format, package version, the full SimConfig, seeds, shapes, sha256s
    shard-00000.npz       scan, mask, target: float32 (n_k, 1, S, S) each  [+ points (n_k, rays, 3)]
    shard-00001.npz
    ...

Shard ``k`` holds ``generate_batch(n_k, sim, seed=shard_seed(seed, k))`` with
``shard_seed(seed, k) = batch_seed(seed, 0, k)`` (``warp_terrain.data.seeds``) and
``n_k = min(shard_size, count - k * shard_size)``: it is exactly batch ``k`` of rank 0 of the
training stream with ``train.seed = seed`` and ``train.batch_size = shard_size`` (sample ``b`` of a
batch depends only on ``(sim, seed, b)``, so a shorter last shard is the start of that batch).
Points are left out by default (they are 10-50x the size of the maps and training does not use
them); ``with_points=True`` stores them as ``points``, NaN rows for rays without a return.

The ``.npz`` files are ordinary numpy archives (``np.load`` reads them), written deterministically
(fixed zip timestamps, deflate), so the same command writes byte-identical shards; each is written
atomically (temporary file in the folder, then ``os.replace``) and the manifest is written last.

:class:`DiskPairs` reads a dataset back: item ``k`` is shard ``k`` as the training stream's dict
``{"scan", "mask", "target"}`` of torch tensors; :meth:`DiskPairs.batches` yields training batches
by step (epoch 0 in order, so with ``shard_size == batch_size`` the first epoch is the stream's
batches exactly; later epochs shuffled from ``(seed, rank, epoch)``). Opening checks the manifest
and every shard's size and sha256, and names the shard that is missing or corrupt.
"""

from __future__ import annotations

import hashlib
import io
import json
import multiprocessing
import os
import zipfile
from collections import OrderedDict
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
import warp as wp
from torch.utils.data import Dataset

from ..core.atomic import atomic_open
from ..core.version import __version__
from ..sim import as_sim_config, generate_batch, resolve_device
from .seeds import shard_seed

__all__ = ["FORMAT", "FORMAT_VERSION", "MANIFEST", "DatasetError", "DiskPairs", "shard_name", "shard_seed", "write_dataset"]

FORMAT = "warp-terrain-dataset"
FORMAT_VERSION = 1
MANIFEST = "manifest.json"
MAPS = ("scan", "mask", "target")
SEED_RULE = (
    "shard k holds generate_batch(n_k, sim, seed=batch_seed(seed, 0, k)) with n_k = min(shard_size, count - k*shard_size) "
    "(batch_seed from warp_terrain.data.stream): batch k of rank 0 of the training stream with train.seed=seed"
)


class DatasetError(ValueError):
    """A dataset folder that cannot be written or read: names the folder or shard and the problem."""


def shard_name(k: int) -> str:
    return f"shard-{k:05d}.npz"


# ------------------------------------------------------------------------------ writing
def _npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """An ``.npz`` archive (deflated) with fixed timestamps: equal arrays give equal bytes."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, array in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.ascontiguousarray(array), allow_pickle=False)
    return buf.getvalue()


def _atomic_write(path: Path, data: bytes) -> None:
    with atomic_open(path) as f:
        f.write(data)


def _positive_int(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name}={value!r}: must be an integer >= 1")
    return int(value)


def _prepare_folder(out: Path, overwrite: bool) -> None:
    if out.exists() and not out.is_dir():
        raise DatasetError(f"out={str(out)!r}: is a file, not a folder")
    if out.is_dir():
        entries = sorted(p.name for p in out.iterdir())
        if entries and not overwrite:
            raise DatasetError(f"out={str(out)!r}: the folder is not empty ({len(entries)} entries, e.g. {entries[0]!r}); "
                               "pass --overwrite (overwrite=True) to replace a dataset there")
        if not os.access(out, os.W_OK | os.X_OK):
            raise DatasetError(f"out={str(out)!r}: no permission to write in the folder")
        return
    try:
        out.mkdir(parents=True)
    except OSError as err:
        raise DatasetError(f"out={str(out)!r}: cannot create the folder ({err.strerror or err})") from None


def _shard(sim, n: int, s_seed: int, with_points: bool, device: str) -> tuple[bytes, dict]:
    """One shard's ``.npz`` bytes and array shapes (top level: worker processes call it)."""
    b = generate_batch(n, sim, seed=s_seed, device=device)
    arrays = {name: getattr(b, name).detach().to("cpu", torch.float32).numpy() for name in MAPS}
    if with_points:
        arrays["points"] = b.points.detach().to("cpu", torch.float32).numpy()
    return _npz_bytes(arrays), {key: list(a.shape) for key, a in arrays.items()}


def _write_shard(out: Path, name: str, data: bytes) -> None:
    try:
        _atomic_write(out / name, data)
    except OSError as err:
        raise DatasetError(f"out={str(out)!r}: cannot write {name} ({err.strerror or err})") from None


def write_dataset(out, count: int, sim=None, seed: int = 0, shard_size: int = 64, overwrite: bool = False,
                  with_points: bool = False, device=None, progress=None, workers: int = 0, track=None) -> dict:
    """Generate ``count`` pairs from ``sim`` (a ``SimConfig`` or anything ``as_sim_config`` takes)
    into the folder ``out`` as shards of ``shard_size``; returns the manifest (also written as
    ``out/manifest.json``).

    ``out`` is created if missing; a non-empty folder is refused unless ``overwrite`` (then its
    ``manifest.json`` and ``shard-*.npz`` are removed first; other files are left alone).
    ``progress``: optional ``callable(str)`` told about each shard; ``track``: optional
    ``track(shards, "generate")`` that yields the shard plan in order while showing progress (the
    CLI passes a tqdm bar on stderr). ``workers`` > 0 makes the
    shards in that many processes (CPU only: a Warp CPU launch runs on one thread); the files
    are the same byte for byte.
    """
    count = _positive_int("count", count)
    shard_size = _positive_int("shard_size", shard_size)
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 0:
        raise ValueError(f"workers={workers!r}: must be an integer >= 0")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed={seed!r}: must be an integer >= 0")
    seed = int(seed)
    sim = as_sim_config(sim)
    device = resolve_device(device)
    out = Path(out)
    _prepare_folder(out, overwrite)
    if overwrite:
        for old in [out / MANIFEST, *out.glob("shard-*.npz")]:
            if old.is_file():
                old.unlink()

    S = sim.data.map_size
    plan = [(k, first, min(shard_size, count - first), shard_seed(seed, k)) for k, first in enumerate(range(0, count, shard_size))]
    jobs = [(sim, n, s_seed, with_points, device) for _k, _first, n, s_seed in plan]
    pool = None
    if workers and device == "cpu" and len(plan) > 1:
        pool = ProcessPoolExecutor(max_workers=int(workers), mp_context=multiprocessing.get_context("spawn"))
        made = pool.map(_shard, *zip(*jobs))  # in shard order
    else:
        made = (_shard(*job) for job in jobs)
    shards = []
    try:
        for (k, first, n, s_seed), (data, shapes) in zip(plan if track is None else track(plan, "generate"), made):
            name = shard_name(k)
            _write_shard(out, name, data)
            shards.append({
                "file": name,
                "index": k,
                "first": first,
                "count": n,
                "seed": s_seed,
                "bytes": len(data),
                "sha256": hashlib.sha256(data).hexdigest(),
                "shapes": shapes,
            })
            if progress is not None:
                progress(f"{name}: {n} pairs (samples {first}..{first + n - 1}, seed {s_seed})")
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)

    arrays_info = {name: {"dtype": "float32", "sample_shape": [1, S, S]} for name in MAPS}
    if with_points:
        arrays_info["points"] = {"dtype": "float32", "sample_shape": shards[0]["shapes"]["points"][1:]}
    manifest = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "warp_terrain_version": __version__,
        "warp_version": wp.config.version,
        "torch_version": torch.__version__.split("+")[0],
        "device": device,
        "count": count,
        "shard_size": shard_size,
        "seed": seed,
        "seed_rule": SEED_RULE,
        "with_points": bool(with_points),
        "arrays": arrays_info,
        "sim": asdict(sim),
        "shards": shards,
    }
    try:
        _atomic_write(out / MANIFEST, (json.dumps(manifest, indent=2) + "\n").encode())
    except OSError as err:
        raise DatasetError(f"out={str(out)!r}: cannot write {MANIFEST} ({err.strerror or err})") from None
    return manifest


# ------------------------------------------------------------------------------ reading
def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _mix64(x: np.ndarray) -> np.ndarray:
    """splitmix64's finaliser on uint64 arrays (wrapping arithmetic): a stable integer hash."""
    x = x.copy()
    x ^= x >> np.uint64(30)
    x *= np.uint64(0xBF58476D1CE4E5B9)
    x ^= x >> np.uint64(27)
    x *= np.uint64(0x94D049BB133111EB)
    x ^= x >> np.uint64(31)
    return x


class DiskPairs(Dataset):
    """A dataset written by :func:`write_dataset`, read back as the training stream's batches.

    Map-style over shards: ``len(pairs)`` shards, ``pairs[k]`` is shard ``k`` as
    ``{"scan", "mask", "target"}`` float32 ``(n_k, 1, S, S)`` tensors (plus ``"points"`` with
    ``with_points=True``, if stored): the same as ``make_pair(sim, n_k, shard_seed(seed, k))``.
    :meth:`samples` gathers any samples, :meth:`batch` / :meth:`batches` make training batches by step.

    Opening reads ``manifest.json``, checks its format and consistency and (``verify=True``)
    every shard's size and sha256; a missing or corrupt shard raises :class:`DatasetError` naming
    it. Loaded shards are kept in memory (at most ``cache_shards`` of them; None: all).
    """

    def __init__(self, folder, verify: bool = True, with_points: bool = False, cache_shards: int | None = None):
        self.folder = Path(folder)
        self.with_points = bool(with_points)
        self.manifest = self._read_manifest()
        m = self.manifest
        self.count, self.shard_size, self.seed = int(m["count"]), int(m["shard_size"]), int(m["seed"])
        self.shards = m["shards"]
        self.map_size = int(m["arrays"]["scan"]["sample_shape"][-1])
        if self.with_points and not m.get("with_points"):
            raise DatasetError(f"dataset {str(self.folder)!r}: written without points (generate --with-points)")

        try:
            self.sim = as_sim_config(m["sim"])
        except Exception as err:
            raise DatasetError(f"dataset {str(self.folder)!r}: the manifest's sim config is invalid ({' '.join(str(err).split())[:200]})") from None
        self._keys = MAPS + (("points",) if self.with_points else ())
        self._cache: OrderedDict[int, dict[str, torch.Tensor]] = OrderedDict()
        self._cache_shards = cache_shards
        self._orders: dict[tuple[int, int, int], np.ndarray] = {}
        if verify:
            self.verify()

    # -- checks ---------------------------------------------------------------------------
    def _fail(self, why: str) -> DatasetError:
        return DatasetError(f"dataset {str(self.folder)!r}: {why}")

    def _read_manifest(self) -> dict:
        if not self.folder.is_dir():
            raise self._fail("no such folder")
        path = self.folder / MANIFEST
        if not path.is_file():
            raise self._fail(f"no {MANIFEST} (not a dataset written by `warp-terrain generate`, or still being written)")
        try:
            m = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
            raise self._fail(f"{MANIFEST} cannot be read ({type(err).__name__}: {err})") from None
        if not isinstance(m, dict) or m.get("format") != FORMAT:
            raise self._fail(f"{MANIFEST} is not a {FORMAT} manifest")
        if not isinstance(m.get("format_version"), int) or m["format_version"] > FORMAT_VERSION:
            raise self._fail(f"format_version {m.get('format_version')!r} is newer than this package reads ({FORMAT_VERSION})")
        for key in ("count", "shard_size", "seed", "sim", "shards", "arrays"):
            if key not in m:
                raise self._fail(f"{MANIFEST} lacks {key!r}")
        shards = m["shards"]
        if not isinstance(shards, list) or not shards:
            raise self._fail(f"{MANIFEST} lists no shards")
        first = 0
        for k, s in enumerate(shards):
            if not isinstance(s, dict) or any(key not in s for key in ("file", "count", "sha256", "bytes", "shapes")):
                raise self._fail(f"{MANIFEST}: shard entry {k} is incomplete")
            if s["file"] != shard_name(k) or int(s.get("first", first)) != first:
                raise self._fail(f"{MANIFEST}: shard entry {k} is out of order ({s['file']!r})")
            want = min(int(m["shard_size"]), int(m["count"]) - first)
            if int(s["count"]) != want:
                raise self._fail(f"{MANIFEST}: {s['file']} holds {s['count']} pairs, expected {want}")
            first += int(s["count"])
        if first != int(m["count"]):
            raise self._fail(f"{MANIFEST}: shards hold {first} pairs but count is {m['count']}")
        return m

    def verify(self) -> None:
        """Check every shard's presence, size and sha256 against the manifest."""
        for s in self.shards:
            path = self.folder / s["file"]
            if not path.is_file():
                raise self._fail(f"shard {s['file']} is missing")
            size = path.stat().st_size
            if size != int(s["bytes"]):
                raise self._fail(f"shard {s['file']} is corrupt: {size} bytes, the manifest says {s['bytes']}")
            if _sha256(path) != s["sha256"]:
                raise self._fail(f"shard {s['file']} is corrupt: its sha256 differs from the manifest's")

    def check_compatible(self, sim) -> None:
        """Raise if the dataset's maps cannot feed a run configured with ``sim`` (map size)."""
        if int(sim.data.map_size) != self.map_size:
            raise self._fail(f"its maps are {self.map_size}x{self.map_size} but the run's data.map_size is {sim.data.map_size}")

    # -- access ---------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.shards)

    def __getitem__(self, k: int) -> dict[str, torch.Tensor]:
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
            raise TypeError(f"shard index must be an integer, got {type(k).__name__}")
        if not -len(self) <= k < len(self):
            raise IndexError(f"shard {k} out of range ({len(self)} shards)")
        return dict(self._shard(int(k) % len(self)))

    def __iter__(self) -> Iterator[dict[str, torch.Tensor]]:
        for k in range(len(self)):
            yield self[k]

    def _shard(self, k: int) -> dict[str, torch.Tensor]:
        if k in self._cache:
            self._cache.move_to_end(k)
            return self._cache[k]
        s = self.shards[k]
        path = self.folder / s["file"]
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {key: z[key] for key in self._keys}
        except KeyError as err:
            raise self._fail(f"shard {s['file']} is corrupt: no array {err}") from None
        except FileNotFoundError:
            raise self._fail(f"shard {s['file']} is missing") from None
        except Exception as err:
            raise self._fail(f"shard {s['file']} is corrupt ({type(err).__name__}: {err})") from None
        tensors = {}
        for key, a in arrays.items():
            if list(a.shape) != list(s["shapes"][key]) or a.dtype != np.float32:
                raise self._fail(f"shard {s['file']} is corrupt: {key} is {a.dtype} {tuple(a.shape)}, "
                                 f"the manifest says float32 {tuple(s['shapes'][key])}")
            tensors[key] = torch.from_numpy(a)
        self._cache[k] = tensors
        if self._cache_shards is not None:
            while len(self._cache) > max(1, int(self._cache_shards)):
                self._cache.popitem(last=False)
        return tensors

    def samples(self, indices) -> dict[str, torch.Tensor]:
        """The samples at global ``indices`` (0..count-1) stacked into one batch dict."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        if idx.size == 0 or idx.min() < 0 or idx.max() >= self.count:
            raise IndexError(f"sample indices must lie in [0, {self.count})")
        rows = {key: [] for key in self._keys}
        for i in idx:
            shard = self._shard(int(i) // self.shard_size)
            for key in self._keys:
                rows[key].append(shard[key][int(i) % self.shard_size])
        return {key: torch.stack(v) for key, v in rows.items()}

    # -- training order -------------------------------------------------------------------
    def order(self, epoch: int, seed: int = 0, rank: int = 0) -> np.ndarray:
        """The sample order of ``epoch``: in order for epoch 0 of rank 0, else a permutation
        drawn from ``(seed, rank, epoch)`` (a fixed integer hash: the same on every machine)."""
        if epoch == 0 and rank == 0:
            return np.arange(self.count)
        key = (int(seed), int(rank), int(epoch))
        if key not in self._orders:
            base = _mix64(np.array([(seed & 0xFFFFFFFF) << 32 | (rank & 0xFFFF) << 16 | 0x5EED], dtype=np.uint64))
            base = _mix64(base ^ np.uint64(epoch & 0xFFFFFFFFFFFF))
            keys = _mix64(np.arange(self.count, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15) + base)
            if len(self._orders) > 4:
                self._orders.clear()
            self._orders[key] = np.argsort(keys, kind="stable")
        return self._orders[key]

    def batch(self, step: int, batch_size: int, seed: int = 0, rank: int = 0) -> dict[str, torch.Tensor]:
        """Training batch ``step``: positions ``step*batch_size ..`` of the endless sequence of
        epochs (each epoch every sample once, in :meth:`order`)."""
        pos = np.arange(step * batch_size, (step + 1) * batch_size, dtype=np.int64)
        epochs, within = np.divmod(pos, self.count)
        idx = np.empty_like(pos)
        for e in np.unique(epochs):
            sel = epochs == e
            idx[sel] = self.order(int(e), seed, rank)[within[sel]]
        return self.samples(idx)

    def batches(self, batch_size: int, seed: int = 0, rank: int = 0, start: int = 0, stop: int | None = None) -> Iterator[dict[str, torch.Tensor]]:
        """Batches ``start, start+1, ...`` (until ``stop``) as dicts with ``"step"``, like the stream."""
        batch_size = _positive_int("batch_size", batch_size)
        step = int(start)
        while stop is None or step < stop:
            pair = self.batch(step, batch_size, seed, rank)
            pair["step"] = torch.tensor(step)
            yield pair
            step += 1
