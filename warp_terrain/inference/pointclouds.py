"""Point clouds from files, through maintained readers, into the sensor frame.

``.npy`` / ``.npz`` (numpy: ``(N, 3+)`` arrays, extra columns such as intensity ignored, or
structured arrays with x/y/z fields), KITTI ``.bin`` (float32 x, y, z, intensity), ``.xyz`` /
``.csv`` / ``.txt`` (numpy text: whitespace or commas, an optional header naming x, y, z),
``.ply`` (plyfile), ``.pcd`` (pypcd4), ``.las`` / ``.laz`` (laspy, with lazrs for compressed
files). Every reader returns an ``(N, 3)`` float64 array of x, y, z: a georeferenced cloud (UTM,
x ~ 5e5 m) keeps its millimetres until a ``sensor_to_ground``-style 4x4 transform (or x, y, z,
roll, pitch, yaw), applied in float64, has moved it into the sensor frame warp-terrain expects
(gravity-aligned, origin at the LIDAR); the model casts to float32 only then.
"""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import numpy as np

READERS = {".npy", ".npz", ".bin", ".xyz", ".csv", ".txt", ".ply", ".pcd", ".las", ".laz"}
TEXT = {".xyz", ".csv", ".txt"}


def _need(module: str, extra: str = "io"):
    try:
        return __import__(module)
    except ImportError:
        raise ValueError(f"reading this format needs {module!r}: pip install 'warp-terrain[{extra}]'") from None


def _first_line(err: BaseException) -> str:
    """A parser's message in one line (pydantic, which pypcd4 uses, prints a page per field)."""
    errors = getattr(err, "errors", None)
    if callable(errors):  # a pydantic ValidationError: the first bad header field
        try:
            first = errors()[0]
            return f"header field {'.'.join(str(k) for k in first['loc'])}: {first['msg']}"[:200]
        except Exception:  # noqa: BLE001  (not pydantic after all: fall back to the message)
            pass
    return (str(err).strip().splitlines() or [type(err).__name__])[0][:200]


def read_point_cloud(path: str | Path) -> np.ndarray:
    """``(N, 3)`` float64 points from a file; ValueError naming the file for anything unreadable."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in READERS:
        raise ValueError(f"{str(path)!r}: unsupported point-cloud format {suffix or '(none)'!r}; use one of {', '.join(sorted(READERS))}")
    if not path.is_file():
        raise ValueError(f"{str(path)!r}: no such file")
    try:
        if suffix == ".npy":
            xyz = xyz_columns(np.load(path, allow_pickle=False))
        elif suffix == ".npz":
            xyz = _read_npz(path)
        elif suffix == ".bin":
            xyz = _read_kitti(path)
        elif suffix in TEXT:
            xyz = _read_text(path)
        elif suffix == ".ply":
            plyfile = _need("plyfile")
            vertex = plyfile.PlyData.read(str(path))["vertex"]
            xyz = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=-1)
        elif suffix == ".pcd":
            pypcd4 = _need("pypcd4")
            cloud = pypcd4.PointCloud.from_path(str(path))
            xyz = np.stack([cloud.pc_data[k].reshape(-1) for k in ("x", "y", "z")], axis=-1)  # a 1-point ASCII file is 0-d
        else:
            laspy = _need("laspy")
            las = laspy.read(str(path))
            xyz = np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], axis=-1)  # float64: scale * int + offset
    except ValueError as err:
        raise ValueError(f"{str(path)!r}: cannot read ({_first_line(err)})") from None
    except Exception as err:  # a corrupt or foreign file: say which, not a parser trace
        raise ValueError(f"{str(path)!r}: cannot read as {suffix} ({type(err).__name__}: {_first_line(err)})") from None
    return check_points(xyz, name=str(path), dtype=np.float64)


def xyz_columns(array: np.ndarray) -> np.ndarray:
    """x, y, z of an array read from a file: the x/y/z fields of a structured array, or the first
    three columns of an ``(N, 3+)`` one (intensity, ring, time... ignored)."""
    if array.dtype.names is not None:
        missing = [k for k in ("x", "y", "z") if k not in array.dtype.names]
        if missing:
            raise ValueError(f"a structured array needs fields x, y, z; it has {', '.join(array.dtype.names)}")
        return np.stack([array[k].reshape(-1) for k in ("x", "y", "z")], axis=-1)
    if array.ndim != 2 or array.shape[1] < 3:
        raise ValueError(f"expected an (N, 3) array of x, y, z (extra columns such as intensity are ignored), got shape {array.shape}")
    return array[:, :3]


def _read_npz(path: Path) -> np.ndarray:
    with np.load(path, allow_pickle=False) as npz:
        names = list(npz.files)
        for key in ("points", "xyz"):
            if key in names:
                return xyz_columns(npz[key])
        if all(k in names for k in ("x", "y", "z")):
            x, y, z = (np.asarray(npz[k]).reshape(-1) for k in ("x", "y", "z"))
            if not len(x) == len(y) == len(z):
                raise ValueError(f"arrays x, y, z have different lengths {len(x)}, {len(y)}, {len(z)}")
            return np.stack([x, y, z], axis=-1)
    raise ValueError("expected an array named 'points' or 'xyz' ((N, 3+) or with x/y/z fields) or arrays 'x', 'y', 'z'; "
                     f"found {', '.join(repr(n) for n in names) or 'no arrays'}")


def _read_kitti(path: Path) -> np.ndarray:
    size = path.stat().st_size
    if size % 16:
        raise ValueError(f"{size} bytes is not a multiple of 16 (a KITTI .bin holds float32 x, y, z, intensity per point)")
    return np.fromfile(path, dtype="<f4").reshape(-1, 4)[:, :3]


def _numbers(tokens: list[str]) -> bool:
    try:
        [float(t) for t in tokens]
    except ValueError:
        return False
    return bool(tokens)


def _read_text(path: Path) -> np.ndarray:
    """Whitespace-, comma- or semicolon-separated columns (the first data line says which); a line
    of names before the data is a header (``#`` or ``//`` before it allowed), whose x, y, z pick
    their columns (else the first three are x, y, z); ``#`` lines are comments."""
    header, header_line, first = None, -1, None
    with open(path, encoding="utf-8") as f:
        for number, line in enumerate(f):
            text = line.strip()
            if not text:
                continue
            tokens = [t.strip("\"'").lower() for t in re.split(r"[,;\s]+", text.lstrip("#/").strip()) if t]
            if _numbers(tokens):
                first = text
                break
            if header is None:
                header, header_line = tokens, number
    if first is None:
        return np.zeros((0, 3))
    delimiter = "," if "," in first else (";" if ";" in first else None)
    columns = (0, 1, 2)
    if header is not None and all(k in header for k in ("x", "y", "z")):
        columns = tuple(header.index(k) for k in ("x", "y", "z"))
    width = len(first.split(delimiter))
    if width < 3 or max(columns) >= width:
        raise ValueError(f"the first data line has {width} column(s), expected x, y, z in columns {', '.join(str(c + 1) for c in columns)}")
    xyz = np.loadtxt(path, delimiter=delimiter, skiprows=header_line + 1, usecols=columns, comments="#", ndmin=2,
                     dtype=np.float64, encoding="utf-8")
    return xyz.reshape(-1, 3)


def check_points(points, name: str = "points", dtype=np.float32) -> np.ndarray:
    """Validate an (N, 3) cloud and return it as ``dtype``: wrong shape/dtype or nothing usable
    -> ValueError; rows with NaN/inf are dropped with a warning."""
    arr = np.asarray(points)
    if arr.dtype.kind not in "iuf":  # ints and floats; not bool, complex, timedelta, objects
        raise ValueError(f"{name}: expected numeric x, y, z, got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name}: expected an (N, 3) array of x, y, z, got shape {arr.shape}")
    if arr.shape[0] == 0:
        raise ValueError(f"{name}: the point cloud is empty")
    with np.errstate(over="ignore"):  # float64 beyond float32's range becomes inf: dropped below
        arr = arr.astype(dtype)
    finite = np.isfinite(arr).all(axis=1)
    if not finite.all():
        dropped = int((~finite).sum())
        if dropped == arr.shape[0]:
            raise ValueError(f"{name}: all {dropped} points have NaN or inf coordinates")
        warnings.warn(f"{name}: dropped {dropped} of {arr.shape[0]} points with NaN or inf coordinates", stacklevel=2)
        arr = arr[finite]
    return np.ascontiguousarray(arr)


def transform_matrix(spec) -> np.ndarray:
    """A 4x4 transform from a 4x4 (or 16-value) matrix or 6 values ``x, y, z, roll, pitch, yaw``
    (metres, degrees; rotation R = Rz(yaw) Ry(pitch) Rx(roll))."""
    values = np.asarray(spec, dtype=np.float64).ravel()
    if values.size == 16:
        m = values.reshape(4, 4)
        if not np.allclose(m[3], [0, 0, 0, 1]):
            raise ValueError(f"transform: the last row must be 0 0 0 1, got {m[3].tolist()}")
        return m
    if values.size != 6:
        raise ValueError(f"transform: expected 16 values (4x4) or 6 (x y z roll pitch yaw), got {values.size}")
    x, y, z, roll, pitch, yaw = values
    r, p, w = (math.radians(a) for a in (roll, pitch, yaw))
    rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    rz = np.array([[math.cos(w), -math.sin(w), 0], [math.sin(w), math.cos(w), 0], [0, 0, 1]])
    m = np.eye(4)
    m[:3, :3] = rz @ ry @ rx
    m[:3, 3] = (x, y, z)
    return m


def apply_transform(points: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """``points`` moved by the 4x4 ``matrix``, in float64 (a UTM cloud keeps its millimetres:
    cast to float32 only once the points are near the sensor)."""
    return np.asarray(points, dtype=np.float64) @ matrix[:3, :3].T + matrix[:3, 3]
