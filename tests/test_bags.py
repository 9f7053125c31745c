"""ROS bags in: PointCloud2 decoding, and bags of every kind written here with rosbags' own
writers (ROS 1 .bag, ROS 2 folders with .db3 and .mcap storage, a bare .mcap) read back exactly."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from warp_terrain.cli import main
from warp_terrain.inference.bags import BagClouds, is_bag, pointcloud2_xyz

ROS1, ROS2 = get_typestore(Stores.ROS1_NOETIC), get_typestore(Stores.ROS2_HUMBLE)
PC2 = "sensor_msgs/msg/PointCloud2"
F4, F8, U2 = 7, 8, 4  # sensor_msgs/PointField datatypes


def cloud(k: int) -> np.ndarray:
    """Message k's points: float32-exact, 2 rows of 3 points, near the sensor."""
    base = np.array([[1.5, -2.25, -1.75], [3.0, 4.0, -1.5], [-0.5, 0.75, -2.0], [6.25, 1.0, -1.25], [-3.5, -4.5, -1.875], [0.25, 5.5, -1.625]])
    return base + [0.125 * k, -0.25 * k, 0.0]


def message(typestore, points: np.ndarray, *, bigendian=False, kind="f4", nan_rows=(), stamp=0):
    """A PointCloud2 of ``points`` in 2 rows: fields intensity, x, y, z, ring at uneven offsets,
    padding inside each point and at the end of each row, NaN in ``nan_rows``."""
    order = ">" if bigendian else "<"
    size = np.dtype(kind).itemsize
    offsets = {"intensity": 0, "x": 4, "y": 4 + size, "z": 4 + 2 * size}
    ring = offsets["z"] + size + 2
    point_step = ring + 2 + 3  # 3 bytes of padding
    layout = np.dtype({"names": ["intensity", "x", "y", "z", "ring"],
                       "formats": [order + "f4", order + kind, order + kind, order + kind, order + "u2"],
                       "offsets": [0, offsets["x"], offsets["y"], offsets["z"], ring], "itemsize": point_step})
    width, height = len(points) // 2, 2
    row_step = width * point_step + 5  # 5 bytes of row padding
    data = np.zeros(height * row_step, np.uint8)
    for r in range(height):
        row = np.zeros(width, layout)
        for c, key in enumerate("xyz"):
            row[key] = points[r * width:(r + 1) * width, c]
        row["intensity"], row["ring"] = 99.0, r
        for i in nan_rows:
            if i // width == r:
                row["z"][i % width] = np.nan
        data[r * row_step:r * row_step + width * point_step] = np.frombuffer(row.tobytes(), np.uint8)
    types = typestore.types
    datatype = {"f4": F4, "f8": F8}[kind]
    fields = [types["sensor_msgs/msg/PointField"](name=n, offset=o, datatype=d, count=1)
              for n, o, d in [("intensity", 0, F4), ("x", offsets["x"], datatype), ("y", offsets["y"], datatype),
                              ("z", offsets["z"], datatype), ("ring", ring, U2)]]
    time = types["builtin_interfaces/msg/Time"](sec=stamp, nanosec=0)
    header = (types["std_msgs/msg/Header"](seq=0, stamp=time, frame_id="lidar") if typestore is ROS1
              else types["std_msgs/msg/Header"](stamp=time, frame_id="lidar"))
    return types[PC2](header=header, height=height, width=width, fields=fields, is_bigendian=bigendian,
                      point_step=point_step, row_step=row_step, data=data, is_dense=not nan_rows)


@pytest.mark.parametrize("bigendian", [False, True], ids=["little", "big"])
@pytest.mark.parametrize("kind", ["f4", "f8"])
def test_pointcloud2_decoding_honours_offsets_steps_and_byte_order(bigendian, kind):
    points = cloud(1)
    np.testing.assert_array_equal(pointcloud2_xyz(message(ROS2, points, bigendian=bigendian, kind=kind)), points)
    got = pointcloud2_xyz(message(ROS2, points, bigendian=bigendian, kind=kind, nan_rows=(1, 4)))
    assert got.dtype == np.float64
    np.testing.assert_array_equal(got, points[[0, 2, 3, 5]])  # NaN points dropped


def test_pointcloud2_that_does_not_add_up_is_refused():
    msg = message(ROS2, cloud(0))
    msg.data = msg.data[:-10]
    with pytest.raises(ValueError, match=r"data holds \d+ bytes, its 2 x 3 points need \d+"):
        pointcloud2_xyz(msg)
    msg = message(ROS2, cloud(0))
    msg.fields = [f for f in msg.fields if f.name != "z"]
    with pytest.raises(ValueError, match="without field\\(s\\) z \\(it has intensity, x, y, ring\\)"):
        pointcloud2_xyz(msg)
    msg = message(ROS2, cloud(0))
    msg.point_step = 8
    with pytest.raises(ValueError, match="field 'y': offset 8 does not fit in point_step 8"):
        pointcloud2_xyz(msg)


def write_bag(path, kind: str, topics=("/points",), n=3, extra_topic=True):
    """A bag of ``kind`` with ``n`` PointCloud2 messages (cloud(0), cloud(1), ...) on each topic,
    one message every 0.1 s from t = 1 s, and a std_msgs/String topic beside them."""
    if kind == "ros1":
        writer, typestore, serialize = Writer1(path), ROS1, ROS1.serialize_ros1
    else:
        plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        writer, typestore, serialize = Writer2(path, version=9, storage_plugin=plugin), ROS2, ROS2.serialize_cdr
    with writer:
        connections = [writer.add_connection(t, PC2, typestore=typestore) for t in topics]
        if extra_topic:
            note = writer.add_connection("/note", "std_msgs/msg/String", typestore=typestore)
            writer.write(note, 900_000_000, serialize(typestore.types["std_msgs/msg/String"](data="hello"), "std_msgs/msg/String"))
        for k in range(n):
            for connection in connections:
                writer.write(connection, 1_000_000_000 + k * 100_000_000, serialize(message(typestore, cloud(k), nan_rows=(k,)), PC2))
    return path


def bag_path(tmp_path, kind):
    if kind == "ros1":
        return write_bag(tmp_path / "drive.bag", "ros1")
    if kind == "bare_mcap":  # the .mcap file of a ROS 2 folder, on its own
        folder = write_bag(tmp_path / "folder", "mcap")
        (single,) = folder.glob("*.mcap")
        return shutil.copy(single, tmp_path / "drive.mcap")
    return write_bag(tmp_path / "drive", kind)


@pytest.mark.parametrize("kind", ["ros1", "sqlite", "mcap", "bare_mcap"])
def test_bags_of_each_kind_give_their_clouds_exactly(tmp_path, kind):
    path = bag_path(tmp_path, kind)
    assert is_bag(path)
    clouds = BagClouds(path)
    assert (clouds.topic, clouds.count, len(clouds)) == ("/points", 3, 3)
    got = list(clouds)
    assert [c.index for c in got] == [0, 1, 2]
    assert [c.timestamp for c in got] == [1_000_000_000, 1_100_000_000, 1_200_000_000]
    for k, c in enumerate(got):
        expected = np.delete(cloud(k), k, axis=0)  # message k has its point k set to NaN
        assert c.points.dtype == np.float64
        np.testing.assert_array_equal(c.points, expected)
    every = BagClouds(path, every=2)
    assert len(every) == 2 and [c.index for c in every] == [0, 2]


def test_topics_are_chosen_or_listed(tmp_path):
    path = write_bag(tmp_path / "two", "sqlite", topics=("/front/points", "/rear/points"))
    with pytest.raises(ValueError) as err:
        BagClouds(path)
    assert str(err.value) == (f"{str(path)!r}: 2 PointCloud2 topics, choose one (--topic): "
                              "/front/points (3 messages), /rear/points (3 messages)")
    assert BagClouds(path, topic="/rear/points").count == 3
    with pytest.raises(ValueError) as err:
        BagClouds(path, topic="/points")
    assert str(err.value) == (f"{str(path)!r}: no PointCloud2 topic '/points'; the bag's PointCloud2 topics: "
                              "/front/points (3 messages), /rear/points (3 messages)")
    with pytest.raises(ValueError, match="no PointCloud2 topic '/note'"):
        BagClouds(path, topic="/note")


@pytest.mark.parametrize("kind", ["ros1", "sqlite"])
def test_a_bag_without_pointcloud2_is_refused(tmp_path, kind):
    path = write_bag(tmp_path / ("notes.bag" if kind == "ros1" else "notes"), kind, topics=(), n=0)
    with pytest.raises(ValueError) as err:
        BagClouds(path)
    assert str(err.value) == f"{str(path)!r}: no sensor_msgs/msg/PointCloud2 topic (the bag has /note (std_msgs/msg/String))"


@pytest.mark.parametrize("kind", ["ros1", "bare_mcap"])
def test_a_truncated_bag_is_refused_naming_the_file(tmp_path, kind):
    path = bag_path(tmp_path, kind)
    blob = path.read_bytes()
    cut = tmp_path / f"cut{path.suffix}"
    cut.write_bytes(blob[: len(blob) // 2])
    with pytest.raises(ValueError) as err:
        list(BagClouds(cut))
    assert str(err.value).startswith(f"{str(cut)!r}: cannot read as a ROS bag ("), str(err.value)


def test_missing_bags_and_plain_folders(tmp_path):
    with pytest.raises(ValueError, match="no such file"):
        BagClouds(tmp_path / "gone.bag")
    with pytest.raises(ValueError, match="a folder but not a ROS 2 bag \\(no metadata.yaml\\)"):
        BagClouds(tmp_path)
    assert not is_bag(tmp_path) and not is_bag(tmp_path / "x.npy") and is_bag(tmp_path / "x.bag")
    with pytest.raises(ValueError, match="every=0: must be a whole number >= 1"):
        BagClouds(write_bag(tmp_path / "b.bag", "ros1"), every=0)
def test_reconstruct_writes_one_map_per_nth_message(tmp_path, capsys):
    path = write_bag(tmp_path / "drive.bag", "ros1", n=3)
    out = tmp_path / "maps"
    assert main(["reconstruct", str(path), "--every", "2", "--out", str(out), "--no-tta"]) == 0
    captured = capsys.readouterr()
    reports = [json.loads(line) for line in captured.out.splitlines()]
    assert sorted(p.name for p in out.iterdir()) == ["drive_0000.npz", "drive_0000.png", "drive_0002.npz", "drive_0002.png"]
    assert [(r["topic"], r["index"], r["timestamp"], r["points"]) for r in reports] == [("/points", 0, 1_000_000_000, 5), ("/points", 2, 1_200_000_000, 5)]
    assert [r["map"] for r in reports] == [str(out / "drive_0000.npz"), str(out / "drive_0002.npz")]
    assert "2/2" in captured.err  # the progress bar
    # each map is the one the same points give through a file
    np.save(tmp_path / "two.npy", np.delete(cloud(2), 2, axis=0))
    assert main(["reconstruct", str(tmp_path / "two.npy"), "--out", str(tmp_path / "two.npz"), "--no-tta"]) == 0
    one, other = np.load(out / "drive_0002.npz"), np.load(tmp_path / "two.npz")
    np.testing.assert_array_equal(one["mask"], other["mask"])
    np.testing.assert_array_equal(one["height"], other["height"])
    # again: refused before any work, then replaced with --overwrite; a ROS 2 folder too, with --transform
    assert main(["reconstruct", str(path), "--every", "2", "--out", str(out), "--no-tta"]) == 2
    assert f"{str(out / 'drive_0000.npz')!r}: exists; pass --overwrite to replace it" in capsys.readouterr().err
    assert main(["reconstruct", str(path), "--every", "2", "--out", str(out), "--no-tta", "--overwrite"]) == 0
    folder = write_bag(tmp_path / "run2", "mcap", n=2)
    assert main(["reconstruct", str(folder), "--transform", "0,0,-100,0,0,0", "--no-tta"]) == 0
    assert sorted(p.name for p in (tmp_path / "run2_maps").iterdir()) == ["run2_0000.npz", "run2_0000.png", "run2_0001.npz", "run2_0001.png"]
    moved = np.load(tmp_path / "run2_maps" / "run2_0000.npz")
    np.testing.assert_array_equal(moved["mask"], np.load(out / "drive_0000.npz")["mask"])  # the same points, 100 m lower


def test_a_message_outside_the_map_is_skipped_with_a_warning(tmp_path, capsys):
    path = write_bag(tmp_path / "far.bag", "ros1", n=2)
    assert main(["reconstruct", str(path), "--transform", "1000,0,0,0,0,0", "--out", str(tmp_path / "m"), "--no-tta"]) == 0
    captured = capsys.readouterr()
    assert [json.loads(line)["skipped"] for line in captured.out.splitlines()] == ["none of its 5 points falls inside the map"] * 2
    assert "warning: far.bag: message 1 on /points: none of its 5 points falls inside the map; skipped" in captured.err
    assert list((tmp_path / "m").iterdir()) == []


def test_reconstruct_refuses_contradictions_before_work(tmp_path, capsys):
    path = write_bag(tmp_path / "drive.bag", "ros1", topics=("/a", "/b"), n=1)
    assert main(["reconstruct", str(path), "--out", str(tmp_path / "maps")]) == 2
    assert "choose one (--topic): /a (1 messages), /b (1 messages)" in capsys.readouterr().err
    assert main(["reconstruct", str(path), "--topic", "/a", "--out", str(tmp_path / "m.npz")]) == 2
    assert "a bag gives one map per message: --out names a folder" in capsys.readouterr().err
    assert main(["reconstruct", str(path), str(path), "--topic", "/a"]) == 2
    assert "a ROS bag is read on its own: give one bag per run, not 2 inputs" in capsys.readouterr().err
    assert main(["reconstruct", str(path), "--topic", "/a", "--usd", str(tmp_path / "s.usda")]) == 2
    assert "--usd is not supported for ROS bags yet" in capsys.readouterr().err
    np.save(tmp_path / "p.npy", cloud(0))
    assert main(["reconstruct", str(tmp_path / "p.npy"), "--topic", "/a"]) == 2
    assert "--topic and --every read ROS bags" in capsys.readouterr().err
    assert main(["reconstruct", str(tmp_path / "gone.bag")]) == 2
    assert f"{str(tmp_path / 'gone.bag')!r}: no such file" in capsys.readouterr().err
    assert not (tmp_path / "maps").exists() and not (tmp_path / "drive_maps").exists()
