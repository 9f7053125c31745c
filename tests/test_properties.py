"""Property-based tests (hypothesis) for what takes point clouds from outside: ``project_points``,
the file readers and ``Reconstructor.reconstruct``.

Generated inputs mix ordinary clouds with the awkward ones (empty, single points, NaN/inf rows,
coordinates far beyond the int32 cell-index range, duplicates, every numeric dtype, numpy and
torch, garbage files). Each must give the documented result or a ValueError that says what was
wrong; nothing may crash, hang or wrap around. Runs are reproducible: derandomized, no example
database. Projection runs on the CPU, where the reference below reproduces the kernel's float32
arithmetic bit for bit.
"""

from __future__ import annotations

import time
import warnings

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import warp_terrain as wt
from warp_terrain.inference.pointclouds import check_points, read_point_cloud

BASE = settings(database=None, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


# -- reference ------------------------------------------------------------------------------------
def reference_maps(points, map_size: int, map_cell: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(height, mask, largest |z|)`` per cell, ``(B, S, S)``, by numpy, from the documented rule
    and the kernel's float32 arithmetic: cell ``floor(x / c + (S-1)/2 + 0.5)`` (round half up),
    mean z per cell."""
    p = np.asarray(points.float().numpy() if isinstance(points, torch.Tensor) else points)
    with np.errstate(over="ignore"):
        p = p.astype(np.float32, copy=False)
    p = p[None] if p.ndim == 2 else p
    S, c = map_size, np.float32(map_cell)
    half, one_half = np.float32(0.5 * (S - 1)), np.float32(0.5)
    maps = []
    for scan in p:
        with np.errstate(all="ignore"):
            fi = np.floor(scan[:, 0] / c + half + one_half)
            fj = np.floor(scan[:, 1] / c + half + one_half)
        keep = np.isfinite(scan).all(axis=1) & (fi >= 0) & (fj >= 0) & (fi < S) & (fj < S)
        cell = fi[keep].astype(np.int64) * S + fj[keep].astype(np.int64)
        z = scan[keep, 2].astype(np.float64)
        count = np.bincount(cell, minlength=S * S)
        total = np.bincount(cell, weights=z, minlength=S * S)
        largest = np.zeros(S * S)
        np.maximum.at(largest, cell, np.abs(z))
        maps.append([(total / np.maximum(count, 1)).astype(np.float32), (count > 0).astype(np.float32), largest])
    return tuple(np.stack(m).reshape(-1, S, S) for m in zip(*maps))


def assert_maps_equal(got, expected) -> None:
    """Masks exactly; heights to float32 rounding, plus float64 summation error where large |z|
    cancel in a cell (the kernel sums in float64, in its own order)."""
    height, mask = (t[:, 0].cpu().numpy() for t in got)
    ref_height, ref_mask, largest = expected
    np.testing.assert_array_equal(mask, ref_mask)
    tolerance = 1e-6 * np.abs(ref_height) + 1e-12 * largest + 1e-30
    assert (np.abs(height.astype(np.float64) - ref_height) <= tolerance).all(), np.abs(height - ref_height).max()


# -- strategies -----------------------------------------------------------------------------------
# metres far outside any map (1e300: beyond float32, inf once cast)
HUGE = [1e30, -1e30, -1e38, 3.0e38, 3e9, -3e9, 1e300, -1e300]
# cell indices that land inside the map if they wrap around through int32 or uint32
WRAPPING = [2.0**31, -(2.0**31), 2.0**32, -(2.0**32), 2.0**32 + 1.0, 2.0**33, 2.0**63, 2.0**64]
BAD = [np.nan, np.inf, -np.inf]
# cell offsets at and next to the rounding borders
OFFSETS = [0.0, 0.5, -0.5, 0.4999, -0.4999, 0.5001, -0.5001, 0.25, -0.25]


@st.composite
def map_geometry(draw, max_size: int = 40):
    size = draw(st.integers(1, max_size))
    cell = draw(st.sampled_from([0.25, 0.1, 1 / 3, 0.07, 1.0, 2.5]) | st.floats(1e-3, 10.0))
    return size, cell


@st.composite
def coordinates(draw, shape, size: int, cell: float):
    """x or y values: cell-aligned (centres, rounding borders), anywhere around the map, huge or
    NaN/inf, or 2**31 and more cells away (where a wrapped-around int index would land inside)."""
    n = int(np.prod(shape))
    k = draw(hnp.arrays(np.int64, n, elements=st.integers(-3, size + 2)))
    offset = draw(hnp.arrays(np.float64, n, elements=st.sampled_from(OFFSETS) | st.floats(-0.5, 0.5)))
    aligned = (k - 0.5 * (size - 1) + offset) * cell
    reach = (size + 4) * cell
    anywhere = draw(hnp.arrays(np.float64, n, elements=st.floats(-reach, reach)))
    special = draw(hnp.arrays(np.float64, n, elements=st.sampled_from(HUGE + BAD) | st.floats(-reach, reach)))
    wrapping = aligned + draw(hnp.arrays(np.float64, n, elements=st.sampled_from(WRAPPING))) * cell
    choice = draw(hnp.arrays(np.int8, n, elements=st.sampled_from([0, 0, 0, 1, 1, 2, 3])))
    return np.choose(choice, [aligned, anywhere, special, wrapping]).reshape(shape)


@st.composite
def clouds(draw, max_points: int = 200, batched: bool = True, max_size: int = 40, heights=None):
    """``(points float64 (B, N, 3) or (N, 3), map_size, map_cell)`` with NaN/inf and huge values
    (``heights``: the z strategy; default anything up to +-3e38)."""
    size, cell = draw(map_geometry(max_size))
    n = draw(st.integers(0, max_points))
    batch = draw(st.integers(1, 3)) if batched and draw(st.booleans()) else None
    shape = (n,) if batch is None else (batch, n)
    x = draw(coordinates(shape, size, cell))
    y = draw(coordinates(shape, size, cell))
    heights = heights if heights is not None else st.floats(-1e3, 1e3) | st.sampled_from(BAD + [0.0, 1e30, -3e38, 3e38])
    z = draw(hnp.arrays(np.float64, shape, elements=heights))
    return np.stack([x, y, z], axis=-1), size, cell


DTYPES = ["float64", "float32", "float16", "int64", "int32", "int16", "uint8", "bfloat16"]


def as_input(points: np.ndarray, dtype: str, kind: str):
    """``points`` cast to ``dtype`` (ints: non-finite -> 0, clipped to the type's range) as a numpy
    array or torch tensor."""
    if dtype.startswith(("int", "uint")):
        info = np.iinfo(dtype)
        points = np.clip(np.nan_to_num(points, nan=0.0, posinf=0.0, neginf=0.0), info.min, info.max)
        with np.errstate(invalid="ignore"):
            out = points.astype(dtype)
    elif dtype == "bfloat16":
        with np.errstate(over="ignore"):
            return torch.from_numpy(points.astype(np.float32)).to(torch.bfloat16)
    else:
        with np.errstate(over="ignore"):
            out = points.astype(dtype)
    return torch.from_numpy(out) if kind == "torch" else out


# -- project_points -------------------------------------------------------------------------------
@pytest.mark.slow
@settings(BASE, max_examples=300)
@given(clouds(), st.sampled_from(DTYPES), st.sampled_from(["numpy", "torch"]))
def test_projection_matches_the_numpy_reference(cloud, dtype, kind):
    """Any cloud of any numeric dtype, numpy or torch, bins exactly as the reference: NaN/inf rows
    and points off the map (however huge) are ignored, each cell holds the mean z of its points."""
    points, size, cell = cloud
    points = as_input(points, dtype, kind)
    got = wt.project_points(points, map_size=size, map_cell=cell, device="cpu")
    batch = points.shape[0] if points.ndim == 3 else 1
    assert all(t.shape == (batch, 1, size, size) and t.dtype == torch.float32 for t in got)
    assert_maps_equal(got, reference_maps(points, size, cell))


@settings(BASE, max_examples=120)
@given(clouds(max_points=60, batched=False), st.integers(2, 5), st.randoms(use_true_random=False))
def test_duplicates_and_order_do_not_change_the_map(cloud, copies, rnd):
    """Every point repeated ``copies`` times, and the rows shuffled: the same mask, the same means."""
    points, size, cell = cloud
    with np.errstate(over="ignore"):
        points = points.astype(np.float32)
    expected = reference_maps(points, size, cell)
    assert_maps_equal(wt.project_points(points, map_size=size, map_cell=cell, device="cpu"), expected)
    order = list(range(copies * len(points)))
    rnd.shuffle(order)
    shuffled = np.repeat(points, copies, axis=0)[order]
    assert_maps_equal(wt.project_points(shuffled, map_size=size, map_cell=cell, device="cpu"), expected)


@settings(BASE, max_examples=100)
@given(map_geometry(), st.lists(st.sampled_from(HUGE + BAD + WRAPPING), min_size=2, max_size=2), st.floats(-1e3, 1e3))
def test_huge_coordinates_are_ignored_not_wrapped(geometry, xy, z):
    """A point whose x or y is huge (or NaN/inf) never reaches the map, even where its int32 cell
    index would wrap around; a point at the centre still lands alone."""
    size, cell = geometry
    x, y = (v * cell if v in WRAPPING else v for v in xy)
    points = np.array([[x, 0.0, 7.0], [0.0, y, 7.0], [x, y, 7.0], [0.0, 0.0, z]])
    height, mask = wt.project_points(points, map_size=size, map_cell=cell, device="cpu")
    centre = int(np.floor(np.float32(0.5 * (size - 1)) + np.float32(0.5)))
    assert mask.sum() == 1 and mask[0, 0, centre, centre] == 1
    assert height[0, 0, centre, centre] == np.float32(z)


def test_large_heights_average_without_overflow():
    """Two points of z = 3e38 in a cell average to 3e38 (a float32 running sum would give inf)."""
    points = np.array([[0.0, 0.0, 3e38], [0.0, 0.0, 3e38], [1.0, 0.0, -3e38], [1.0, 0.0, 3e38]], np.float32)
    height, mask = wt.project_points(points, map_size=3, map_cell=1.0, device="cpu")
    assert height[0, 0, 1, 1] == np.float32(3e38) and height[0, 0, 2, 1] == 0.0 and mask.sum() == 2


@settings(BASE, max_examples=100)
@given(
    st.one_of(
        hnp.array_shapes(min_dims=1, max_dims=1, max_side=6),
        st.tuples(st.integers(0, 5), st.integers(0, 6).filter(lambda d: d != 3)),
        st.tuples(st.integers(1, 3), st.integers(0, 5), st.integers(0, 6).filter(lambda d: d != 3)),
        hnp.array_shapes(min_dims=4, max_dims=5, max_side=3),
        st.tuples(st.just(0), st.integers(0, 4), st.just(3)),
    ),
    st.sampled_from(["numpy", "torch"]),
)
def test_wrong_shapes_raise_a_value_error_naming_points(shape, kind):
    """Anything but ``(N, 3)`` or ``(B >= 1, N, 3)`` is refused with a ValueError about ``points``."""
    points = np.zeros(shape, np.float32)
    with pytest.raises(ValueError, match="points"):
        wt.project_points(torch.from_numpy(points) if kind == "torch" else points, map_size=5, device="cpu")


@pytest.mark.parametrize(
    "points",
    [
        np.array([["a", "b", "c"]]),
        np.array([[{}, {}, {}]], dtype=object),
        np.array([[1.0, 2.0, 3.0]], dtype=object),
        np.ones((2, 3), complex),
        np.ones((2, 3), bool),
        np.zeros(2, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")]),
        np.ones((2, 3), "m8[s]"),
        [[0.0, 0.0], [1.0, 2.0, 3.0]],
        torch.ones(2, 3, dtype=torch.complex64),
        torch.ones(2, 3, dtype=torch.bool),
        None,
        "points",
    ],
    ids=["str", "object-dict", "object-number", "complex", "bool", "structured", "timedelta", "ragged", "torch-complex", "torch-bool", "none", "string"],
)
def test_wrong_dtypes_raise_a_value_error_naming_points(points):
    with pytest.raises(ValueError, match="points"):
        wt.project_points(points, map_size=5, device="cpu")


@settings(BASE, max_examples=50)
@given(st.lists(st.tuples(st.floats(-2, 2), st.floats(-2, 2), st.floats(-10, 10)), max_size=20))
def test_nested_lists_project_like_arrays(rows):
    """Plain Python lists of rows give the same maps as the equivalent float64 array."""
    points = rows if rows else np.zeros((0, 3))
    expected = wt.project_points(np.array(points, np.float64).reshape(-1, 3), map_size=9, map_cell=0.5, device="cpu")
    got = wt.project_points(points, map_size=9, map_cell=0.5, device="cpu")
    for a, b in zip(got, expected):
        torch.testing.assert_close(a, b, rtol=0, atol=0)


def test_ten_million_points():
    """10 M points through ``project_points`` in one call match the bincount reference, and 10 M
    points in a single cell average without float32 drift (a float32 running sum of 0.1 ten million
    times ends near 1.09e6, not 1e6)."""
    rng = np.random.default_rng(7)
    n, size, cell = 10_000_000, 121, 0.25
    points = np.empty((n, 3), np.float32)
    for k in range(2):  # the map spans +-15.125 m
        points[:, k] = rng.random(n, dtype=np.float32) * 32.0 - 16.0
    points[:, 2] = rng.standard_normal(n, dtype=np.float32)
    points[::1000, 0] = np.nan
    start = time.perf_counter()
    got = wt.project_points(points, map_size=size, map_cell=cell, device="cpu")
    seconds = time.perf_counter() - start
    assert_maps_equal(got, reference_maps(points, size, cell))
    assert got[1].sum() == size * size
    print(f"\n10 M points projected on the CPU in {seconds:.2f} s")

    points[:, :2] *= 1e-3  # every point in the centre cell
    points[:, 2] = 0.1
    height, mask = wt.project_points(points, map_size=size, map_cell=cell, device="cpu")
    assert mask.sum() == 1
    assert abs(float(height[0, 0, 60, 60]) - 0.1) < 1e-7


# -- readers --------------------------------------------------------------------------------------
def write_cloud(fmt: str, path, xyz: np.ndarray, data) -> float:
    """Write ``xyz`` in ``fmt`` with generated writer options; return the format's quantisation
    step (0 where it stores the float32 values exactly)."""
    if fmt == "npy":
        dtype = data.draw(st.sampled_from(["float32", "float64"]), label="npy dtype")
        array = xyz.astype(dtype)
        np.save(path, np.asfortranarray(array) if data.draw(st.booleans(), label="fortran") else array)
        return 0.0
    if fmt == "npz":  # a (N, 3+) 'points' / 'xyz' array, or x, y, z arrays
        layout = data.draw(st.sampled_from(["points", "xyz", "columns"]), label="npz layout")
        extra = data.draw(st.integers(0, 2), label="npz extra columns")
        if layout == "columns":
            np.savez(path, x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2])
        else:
            np.savez(path, **{layout: np.concatenate([xyz, np.ones((len(xyz), extra), xyz.dtype)], axis=1)})
        return 0.0
    if fmt == "bin":  # KITTI: float32 x, y, z, intensity
        np.concatenate([xyz, np.full((len(xyz), 1), 0.5, np.float32)], axis=1).astype("<f4").tofile(path)
        return 0.0
    if fmt == "csv":  # text: any separator, a header or none, extra columns; %.17g round-trips exactly
        sep = data.draw(st.sampled_from([",", " ", "\t", ", "]), label="csv separator")
        header = data.draw(st.sampled_from(["", "x,y,z,i", "# x y z i", "i z y x"]), label="csv header")
        columns = np.concatenate([xyz.astype(np.float64), np.full((len(xyz), 1), 7.0)], axis=1)
        if header == "i z y x":
            columns = columns[:, ::-1]
        lines = [sep.join(f"{v:.17g}" for v in row) for row in columns]
        path.write_text("\n".join(([header.replace(",", sep.strip() or " ")] if header else []) + lines) + "\n")
        return 0.0
    if fmt == "ply":
        from plyfile import PlyData, PlyElement

        kind = data.draw(st.sampled_from(["f4", "f8"]), label="ply type")
        vertex = np.empty(len(xyz), dtype=[("x", kind), ("y", kind), ("z", kind)])
        vertex["x"], vertex["y"], vertex["z"] = xyz.T
        text = data.draw(st.booleans(), label="ply ascii")
        order = data.draw(st.sampled_from(["<", ">"]), label="ply byte order")
        PlyData([PlyElement.describe(vertex, "vertex")], text=text, byte_order=order).write(str(path))
        return 0.0
    if fmt == "pcd":
        from pypcd4 import Encoding, PointCloud

        encoding = data.draw(st.sampled_from([Encoding.ASCII, Encoding.BINARY, Encoding.BINARY_COMPRESSED]), label="pcd encoding")
        PointCloud.from_xyz_points(xyz).save(str(path), encoding=encoding)
        return 1e-10 if encoding == Encoding.ASCII else 0.0  # pypcd4 writes ASCII with 10 decimals
    import laspy

    scale = data.draw(st.sampled_from([1e-2, 1e-3, 1e-4]), label="las scale")
    header = laspy.LasHeader(point_format=data.draw(st.sampled_from([0, 3, 6]), label="las format"))
    header.scales = np.full(3, scale)
    header.offsets = np.floor(xyz.min(axis=0).astype(np.float64)) if data.draw(st.booleans(), label="las offset") else np.zeros(3)
    las = laspy.LasData(header)
    las.x, las.y, las.z = (xyz[:, k].astype(np.float64) for k in range(3))
    las.write(str(path))
    return scale


FORMATS = ["npy", "npz", "bin", "csv", "ply", "pcd", "las", "laz"]
FINITE = st.floats(-1e4, 1e4, width=32)  # LAS stores int32 steps of at least 1e-4 around its offset


@settings(BASE, max_examples=200)
@given(st.sampled_from(FORMATS), hnp.arrays(np.float32, st.tuples(st.integers(1, 50), st.just(3)), elements=FINITE), st.data())
def test_files_round_trip(tmp_path_factory, fmt, xyz, data):
    """Finite clouds written in every format (and writer option) read back equal: exactly, or to
    half a quantisation step (+ float32 rounding) for LAS/LAZ."""
    path = tmp_path_factory.mktemp("rt") / f"cloud.{fmt}"
    step = write_cloud(fmt, path, xyz, data)
    got = read_point_cloud(path)
    assert got.dtype == np.float64 and got.shape == xyz.shape and got.flags.c_contiguous  # float64 until the sensor frame
    if step == 0.0:
        np.testing.assert_array_equal(got, xyz)
    else:
        assert (np.abs(got.astype(np.float64) - xyz) <= step / 2 * 1.001 + 1e-6 * np.abs(xyz) + 1e-9).all()


@settings(BASE, max_examples=100)
@given(
    st.sampled_from(["npy", "npz", "bin", "csv", "ply", "pcd"]),
    hnp.arrays(np.float32, st.tuples(st.integers(1, 40), st.just(3)), elements=FINITE),
    st.data(),
)
def test_files_with_nan_rows_drop_them_with_a_warning(tmp_path_factory, fmt, xyz, data):
    """Rows with NaN/inf are dropped with a warning saying how many; all bad -> ValueError."""
    bad = data.draw(hnp.arrays(bool, len(xyz), elements=st.booleans()), label="bad rows")
    bad[data.draw(st.integers(0, len(xyz) - 1), label="one bad row")] = True
    column = data.draw(st.integers(0, 2), label="column")
    dirty = xyz.copy()
    dirty[bad, column] = data.draw(st.sampled_from(BAD), label="value")
    path = tmp_path_factory.mktemp("nan") / f"cloud.{fmt}"
    step = write_cloud(fmt, path, dirty, data)
    if bad.all():
        with pytest.raises(ValueError, match="NaN or inf"):
            read_point_cloud(path)
        return
    with pytest.warns(UserWarning, match=f"dropped {int(bad.sum())} of {len(xyz)}"):
        got = read_point_cloud(path)
    np.testing.assert_allclose(got, xyz[~bad], rtol=1e-6, atol=step / 2 * 1.001)


@pytest.mark.parametrize("fmt", FORMATS)
def test_empty_files_are_refused(tmp_path, fmt):
    """A file with no points, or no bytes at all, is a ValueError naming the file."""
    path = tmp_path / f"empty.{fmt}"
    if fmt == "las" or fmt == "laz":
        import laspy

        laspy.LasData(laspy.LasHeader(point_format=3)).write(str(path))
    elif fmt == "ply":
        from plyfile import PlyData, PlyElement

        PlyData([PlyElement.describe(np.zeros(0, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")]), "vertex")]).write(str(path))
    elif fmt == "pcd":
        path.write_text("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 0\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 0\nDATA binary\n")
    elif fmt == "npz":
        np.savez(path, points=np.zeros((0, 4), np.float32))
    elif fmt == "bin":
        path.write_bytes(b"")
    elif fmt == "csv":
        path.write_text("x,y,z,intensity\n")
    else:
        np.save(path, np.zeros((0, 3), np.float32))
    with pytest.raises(ValueError, match="empty"):
        read_point_cloud(path)
    blank = tmp_path / f"blank.{fmt}"
    blank.write_bytes(b"")
    with pytest.raises(ValueError, match="blank"):
        read_point_cloud(blank)


MAGIC = {"npy": b"\x93NUMPY\x01\x00", "npz": b"PK\x03\x04", "bin": b"\x00\x00\x80\x3f" * 4, "csv": b"x,y,z\n1,2,3\n", "ply": b"ply\nformat binary_little_endian 1.0\n", "pcd": b"# .PCD v0.7\nFIELDS x y z\n", "las": b"LASF", "laz": b"LASF"}


@settings(BASE, max_examples=200)
@given(st.sampled_from(FORMATS), st.booleans(), st.binary(max_size=400))
def test_garbage_files_fail_naming_the_file(tmp_path_factory, fmt, magic, payload):
    """Random bytes (after the format's magic or not) behind a valid suffix: a ValueError naming
    the file, or, if they happen to parse, a valid finite (N, 3) float64 cloud."""
    path = tmp_path_factory.mktemp("junk") / f"junk.{fmt}"
    path.write_bytes((MAGIC[fmt] if magic else b"") + payload)
    try:
        got = read_point_cloud(path)
    except ValueError as err:
        event("refused")
        assert "junk" in str(err)
    else:
        event("parsed")
        assert got.dtype == np.float64 and got.ndim == 2 and got.shape[1] == 3 and np.isfinite(got).all()


@settings(BASE, max_examples=150)
@given(
    st.sampled_from(FORMATS),
    hnp.arrays(np.float32, st.tuples(st.integers(1, 30), st.just(3)), elements=FINITE),
    st.just(1.0) | st.floats(0.0, 1.0),
    st.lists(st.tuples(st.floats(0.0, 1.0), st.binary(min_size=1, max_size=8)), max_size=4),
    st.data(),
)
def test_corrupted_files_fail_naming_the_file(tmp_path_factory, fmt, xyz, keep, patches, data):
    """A valid file cut short and/or with bytes overwritten: a ValueError naming the file, or a
    valid finite (N, 3) float64 cloud, never another exception or a hang."""
    path = tmp_path_factory.mktemp("cut") / f"cut.{fmt}"
    write_cloud(fmt, path, xyz, data)
    blob = bytearray(path.read_bytes())
    for where, patch in patches:
        at = int(where * len(blob))
        blob[at : at + len(patch)] = patch
    path.write_bytes(bytes(blob[: max(1, int(keep * len(blob)))] if keep < 1.0 else blob))
    try:
        got = read_point_cloud(path)
    except ValueError as err:
        event("refused")
        assert "cut" in str(err)
    else:
        event("parsed")
        assert got.dtype == np.float64 and got.ndim == 2 and got.shape[1] == 3 and np.isfinite(got).all()


@pytest.mark.parametrize(
    "header",
    [
        b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 4000000000\nHEIGHT 4000000000\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 16000000000000000000\nDATA binary\n",
        b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
    ],
    ids=["pcd", "ply"],
)
def test_headers_promising_absurd_point_counts_fail_fast(tmp_path, header):
    """A header claiming trillions of points over a few bytes: a ValueError, not a huge allocation."""
    path = tmp_path / ("lying.pcd" if header.startswith(b"#") else "lying.ply")
    path.write_bytes(header + b"\x00" * 24)
    with pytest.raises(ValueError, match="lying"):
        read_point_cloud(path)


UNPICKLED = []


class Payload:
    """Records it if it is ever unpickled."""

    def __reduce__(self):
        return (UNPICKLED.append, ("unpickled",))


@settings(BASE, max_examples=50)
@given(st.lists(st.integers() | st.text(max_size=5) | st.just(Payload()), min_size=1, max_size=6), st.booleans())
def test_pickled_npy_is_refused_unread(tmp_path_factory, items, shaped):
    """An object-dtype .npy (a pickle inside) is a ValueError naming the file; nothing in it runs."""
    array = np.empty(len(items), dtype=object)
    array[:] = items
    if shaped and len(items) % 3 == 0:
        array = array.reshape(-1, 3)
    path = tmp_path_factory.mktemp("pickle") / "pickled.npy"
    np.save(path, array, allow_pickle=True)
    with pytest.raises(ValueError, match="pickled"):
        read_point_cloud(path)
    assert UNPICKLED == []


@settings(BASE, max_examples=60)
@given(hnp.arrays(hnp.scalar_dtypes(), hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=5)))
@example(np.ones((2, 3), "m8[s]"))
@example(np.ones((2, 3), bool))
@example(np.array([[1e300, 0, 0], [1, 2, 3]]))
def test_check_points_accepts_only_usable_clouds(array):
    """Any array of any dtype and shape: a finite C-contiguous (M >= 1, 3) float32 result holding
    the finite rows, or a ValueError naming the cloud."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            got = check_points(array, name="cloud")
    except ValueError as err:
        assert "cloud" in str(err)
        return
    assert array.ndim == 2 and array.shape[1] == 3 and array.dtype.kind in "iuf"
    with np.errstate(over="ignore"):
        expected = array.astype(np.float32)
    np.testing.assert_array_equal(got, expected[np.isfinite(expected).all(axis=1)])
    assert got.dtype == np.float32 and got.flags.c_contiguous and len(got) >= 1 and np.isfinite(got).all()


# -- Reconstructor --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def reconstructor():
    from warp_terrain.inference.reconstructor import Reconstructor

    return Reconstructor.load(device="cpu")


@settings(BASE, max_examples=30)
@given(clouds(max_points=300, batched=False, max_size=121, heights=st.floats(-100, 100) | st.just(np.nan)), st.randoms(use_true_random=False))
def test_reconstruct_is_finite_deterministic_and_order_free(reconstructor, cloud, rnd):
    """The shipped model on any cloud: a finite (S, S) float32 map; bit-identical again without
    the NaN/inf rows (they are dropped, nothing else varies); the same to float tolerance with
    every point given twice and the rows shuffled. A ValueError naming ``points`` exactly when
    nothing usable lands on the map."""
    points, size, cell = cloud
    with np.errstate(over="ignore"):
        as32 = points.astype(np.float32)
    finite = as32[np.isfinite(as32).all(axis=1)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            height = reconstructor.reconstruct(points, map_size=size, map_cell=cell)
        except ValueError as err:
            event("refused")
            assert "points" in str(err)
            _, mask, _ = reference_maps(finite, size, cell)
            assert len(finite) == 0 or mask.sum() == 0
            return
    event("reconstructed")
    assert height.shape == (size, size) and height.dtype == np.float32 and np.isfinite(height).all()
    np.testing.assert_array_equal(reconstructor.reconstruct(finite, map_size=size, map_cell=cell), height)
    order = list(range(2 * len(finite)))
    rnd.shuffle(order)
    doubled = np.concatenate([finite, finite])[order]
    np.testing.assert_allclose(reconstructor.reconstruct(doubled, map_size=size, map_cell=cell), height, rtol=1e-5, atol=1e-5)
