"""Point clouds from files, through maintained readers, into the sensor frame.

``.npy`` (numpy), ``.ply`` (plyfile), ``.pcd`` (pypcd4), ``.las`` / ``.laz`` (laspy, with lazrs
for compressed files). Every reader returns an ``(N, 3)`` float32 array of x, y, z; a
``sensor_to_ground``-style 4x4 transform (or x, y, z, roll, pitch, yaw) moves it into the sensor
frame warp-terrain expects (gravity-aligned, origin at the LIDAR).
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

READERS = {".npy", ".ply", ".pcd", ".las", ".laz"}


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
    """``(N, 3)`` float32 points from a file; ValueError naming the file for anything unreadable."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in READERS:
        raise ValueError(f"{str(path)!r}: unsupported point-cloud format {suffix or '(none)'!r}; use one of {', '.join(sorted(READERS))}")
    if not path.is_file():
        raise ValueError(f"{str(path)!r}: no such file")
    try:
        if suffix == ".npy":
            xyz = np.load(path, allow_pickle=False)
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
            xyz = np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], axis=-1)
    except ValueError as err:
        raise ValueError(f"{str(path)!r}: cannot read ({_first_line(err)})") from None
    except Exception as err:  # a corrupt or foreign file: say which, not a parser trace
        raise ValueError(f"{str(path)!r}: cannot read as {suffix} ({type(err).__name__}: {_first_line(err)})") from None
    return check_points(xyz, name=str(path))


def check_points(points, name: str = "points") -> np.ndarray:
    """Validate an (N, 3) cloud: wrong shape/dtype or nothing usable -> ValueError; rows with
    NaN/inf are dropped with a warning."""
    arr = np.asarray(points)
    if arr.dtype.kind not in "iuf":  # ints and floats; not bool, complex, timedelta, objects
        raise ValueError(f"{name}: expected numeric x, y, z, got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name}: expected an (N, 3) array of x, y, z, got shape {arr.shape}")
    if arr.shape[0] == 0:
        raise ValueError(f"{name}: the point cloud is empty")
    arr = arr.astype(np.float32)
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
    return (points.astype(np.float64) @ matrix[:3, :3].T + matrix[:3, 3]).astype(np.float32)
