"""The point-cloud readers' formats beyond (N, 3) arrays (extra columns, .npz, structured arrays,
KITTI .bin, text), and georeferenced clouds keeping float64 until they are in the sensor frame."""

from __future__ import annotations

import numpy as np
import pytest

import warp_terrain as wt
from warp_terrain.cli import main
from warp_terrain.inference.pointclouds import apply_transform, read_point_cloud, transform_matrix

XYZI = np.array([[1.5, -2.25, 0.125, 7.0], [3.0, 4.0, -5.0, 8.0], [-0.5, 0.75, 2.0, 9.0]], np.float32)


def test_npy_with_extra_columns_keeps_the_first_three(tmp_path):
    for columns in (4, 5, 6):  # x, y, z, intensity, ring, time
        array = np.concatenate([XYZI, np.full((3, columns - 4), 42.0, np.float32)], axis=1)
        np.save(tmp_path / f"c{columns}.npy", array)
        got = read_point_cloud(tmp_path / f"c{columns}.npy")
        assert got.dtype == np.float64
        np.testing.assert_array_equal(got, XYZI[:, :3])
    np.save(tmp_path / "two.npy", XYZI[:, :2])
    with pytest.raises(ValueError, match=r"two.npy.*expected an \(N, 3\) array of x, y, z \(extra columns such as intensity are ignored\), got shape \(3, 2\)"):
        read_point_cloud(tmp_path / "two.npy")


def test_structured_arrays_use_their_xyz_fields(tmp_path):
    cloud = np.zeros(3, dtype=[("intensity", "f4"), ("z", "f8"), ("y", "f4"), ("x", "f4"), ("ring", "u2")])
    cloud["x"], cloud["y"], cloud["z"], cloud["intensity"] = XYZI[:, 0], XYZI[:, 1], XYZI[:, 2], XYZI[:, 3]
    np.save(tmp_path / "s.npy", cloud)
    np.testing.assert_array_equal(read_point_cloud(tmp_path / "s.npy"), XYZI[:, :3])
    np.savez(tmp_path / "s.npz", points=cloud)
    np.testing.assert_array_equal(read_point_cloud(tmp_path / "s.npz"), XYZI[:, :3])
    np.save(tmp_path / "noz.npy", np.zeros(2, dtype=[("x", "f4"), ("y", "f4")]))
    with pytest.raises(ValueError, match="noz.npy.*needs fields x, y, z; it has x, y"):
        read_point_cloud(tmp_path / "noz.npy")


@pytest.mark.parametrize("layout", ["points", "xyz", "columns"])
def test_npz_takes_points_xyz_or_columns(tmp_path, layout):
    path = tmp_path / "c.npz"
    if layout == "columns":
        np.savez(path, x=XYZI[:, 0], y=XYZI[:, 1], z=XYZI[:, 2], intensity=XYZI[:, 3])
    else:
        np.savez(path, **{layout: XYZI, "stamp": np.float64(1.0)})
    np.testing.assert_array_equal(read_point_cloud(path), XYZI[:, :3])


def test_npz_without_points_says_what_it_expected(tmp_path):
    np.savez(tmp_path / "other.npz", cloud=XYZI, t=np.zeros(3))
    with pytest.raises(ValueError) as err:
        read_point_cloud(tmp_path / "other.npz")
    assert str(err.value) == ("'" + str(tmp_path / "other.npz") + "': cannot read (expected an array named 'points' or 'xyz' "
                              "((N, 3+) or with x/y/z fields) or arrays 'x', 'y', 'z'; found 'cloud', 't')")
    np.savez(tmp_path / "ragged.npz", x=np.zeros(3), y=np.zeros(3), z=np.zeros(2))
    with pytest.raises(ValueError, match="ragged.npz.*x, y, z have different lengths 3, 3, 2"):
        read_point_cloud(tmp_path / "ragged.npz")


def test_kitti_bin(tmp_path):
    XYZI.astype("<f4").tofile(tmp_path / "000000.bin")
    got = read_point_cloud(tmp_path / "000000.bin")
    assert got.dtype == np.float64 and got.shape == (3, 3)
    np.testing.assert_array_equal(got, XYZI[:, :3])
    (tmp_path / "cut.bin").write_bytes(XYZI.astype("<f4").tobytes()[:-4])
    with pytest.raises(ValueError) as err:
        read_point_cloud(tmp_path / "cut.bin")
    assert "cut.bin" in str(err.value) and "44 bytes is not a multiple of 16" in str(err.value)


@pytest.mark.parametrize(
    ("name", "text"),
    [
        ("plain.xyz", "1.5 -2.25 0.125 7\n3 4 -5 8\n-0.5 0.75 2 9\n"),
        ("tabs.txt", "1.5\t-2.25\t0.125\n\n3\t4\t-5\n-0.5\t0.75\t2\n"),
        ("header.csv", "x,y,z,intensity\n1.5,-2.25,0.125,7\n3,4,-5,8\n-0.5,0.75,2,9\n"),
        ("reordered.csv", "intensity; Z; Y; X\n7; 0.125; -2.25; 1.5\n8; -5; 4; 3\n9; 2; 0.75; -0.5\n"),
        ("comment.txt", "# exported by a scanner\n1.5 -2.25 0.125\n# a comment\n3 4 -5\n-0.5 0.75 2\n"),
        ("cloudcompare.txt", "//X,Y,Z,R,G,B\n1.5,-2.25,0.125,0,0,0\n3,4,-5,0,0,0\n-0.5,0.75,2,0,0,0\n"),
        ("named.csv", '"time","x","y","z"\n0,1.5,-2.25,0.125\n0,3,4,-5\n0,-0.5,0.75,2\n'),
    ],
)
def test_text_clouds(tmp_path, name, text):
    (tmp_path / name).write_text(text)
    np.testing.assert_array_equal(read_point_cloud(tmp_path / name), XYZI[:, :3])


def test_bad_text_clouds_name_the_file_and_problem(tmp_path):
    cases = {
        "narrow.xyz": ("1 2\n3 4\n", "the first data line has 2 column(s), expected x, y, z in columns 1, 2, 3"),
        "short_row.csv": ("1,2,3\n4,5\n", "invalid column index 2 at row 2 with 2 columns"),
        "words.txt": ("x y z\n1 2 3\nup down left\n", "could not convert string 'up' to float64"),
        "only_header.csv": ("x,y,z\n", "the point cloud is empty"),
    }
    for name, (text, problem) in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(ValueError) as err:
            read_point_cloud(tmp_path / name)
        assert name in str(err.value) and problem in str(err.value), str(err.value)


def test_transform_stays_float64():
    utm = np.array([[512345.678, 4123456.789, 1234.5]])
    got = apply_transform(utm, transform_matrix([-512345.678, -4123456.789, -1234.5, 0, 0, 0]))
    assert got.dtype == np.float64
    np.testing.assert_allclose(got, [[0.0, 0.0, 0.0]], atol=1e-9)


SHIFT = np.array([512345.678, 4123456.789, 1234.5])


def _write_las(path, xyz, offsets):
    import laspy

    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.full(3, 0.001)
    header.offsets = offsets
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.write(str(path))


def test_a_utm_cloud_gives_the_same_map_as_the_local_one(tmp_path, capsys):
    """A simulated scan on the LAS file's millimetre grid, once in local coordinates and once
    shifted into UTM (x ~ 5e5, y ~ 4e6 m) with the inverse --transform: the same map. Reading
    in float32 moved the UTM points by up to 3 cm (203 of 14,641 mask cells differed)."""
    points = wt.generate_batch(1, seed=0, device="cpu").points[0].numpy().astype(np.float64)
    points = np.round(points[np.isfinite(points).all(axis=1)] / 0.001) * 0.001
    _write_las(tmp_path / "local.las", points, np.zeros(3))
    _write_las(tmp_path / "utm.las", points + SHIFT, np.floor(SHIFT))
    back = ",".join(f"{-v}" for v in SHIFT) + ",0,0,0"
    assert main(["reconstruct", str(tmp_path / "local.las"), "--out", str(tmp_path / "local.npz"), "--no-tta"]) == 0
    assert main(["reconstruct", str(tmp_path / "utm.las"), "--transform", back, "--out", str(tmp_path / "utm.npz"), "--no-tta"]) == 0
    local, utm = np.load(tmp_path / "local.npz"), np.load(tmp_path / "utm.npz")
    assert local["mask"].sum() > 2000
    np.testing.assert_array_equal(utm["mask"], local["mask"])
    np.testing.assert_allclose(utm["height"], local["height"], rtol=0, atol=1e-4)
    # the readers' float64 is what keeps it: cast to float32 first, the same cloud moves by centimetres
    lost = apply_transform(read_point_cloud(tmp_path / "utm.las").astype(np.float32), transform_matrix([float(v) for v in back.split(",")]))
    assert np.abs(lost - points).max() > 0.005
