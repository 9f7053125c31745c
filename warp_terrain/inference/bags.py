"""Point clouds from ROS bags, through the pure-Python ``rosbags`` library (no ROS install).

ROS 1 ``.bag`` files, ROS 2 bag folders (``metadata.yaml`` with ``.db3`` or ``.mcap`` storage)
and bare ``.mcap`` / ``.db3`` files. :class:`BagClouds` picks a ``sensor_msgs/msg/PointCloud2``
topic (refusing to guess between several) and yields one ``(N, 3)`` float64 cloud per message,
or per Nth message; :func:`pointcloud2_xyz` decodes one message's x, y, z by their offsets and
datatypes, honouring ``point_step``, ``row_step`` and ``is_bigendian``, and drops NaN points
(an organised cloud marks missing returns with NaN).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .pointclouds import _first_line, _need

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
BAG_SUFFIXES = {".bag", ".mcap", ".db3"}
#: sensor_msgs/PointField datatypes -> numpy type codes (byte order added per message)
POINTFIELD_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def is_bag(path: str | Path) -> bool:
    """A ROS bag by its name: a ``.bag`` / ``.mcap`` / ``.db3`` file or a folder with ``metadata.yaml``."""
    path = Path(path)
    return path.suffix.lower() in BAG_SUFFIXES or (path.is_dir() and (path / "metadata.yaml").is_file())


def pointcloud2_xyz(msg) -> np.ndarray:
    """``(N, 3)`` float64 x, y, z of a ``sensor_msgs/msg/PointCloud2`` message (any object with
    its fields), rows with NaN or inf dropped; ValueError for a message that does not add up."""
    fields = {f.name: f for f in msg.fields}
    missing = [k for k in ("x", "y", "z") if k not in fields]
    if missing:
        raise ValueError(f"PointCloud2 without field(s) {', '.join(missing)} (it has {', '.join(fields) or 'none'})")
    height, width, point_step, row_step = int(msg.height), int(msg.width), int(msg.point_step), int(msg.row_step)
    order = ">" if msg.is_bigendian else "<"
    formats, offsets = [], []
    for k in ("x", "y", "z"):
        field = fields[k]
        if field.datatype not in POINTFIELD_TYPES:
            raise ValueError(f"PointCloud2 field {k!r}: unknown datatype {field.datatype}")
        dtype = np.dtype(order + POINTFIELD_TYPES[field.datatype])
        if field.offset < 0 or field.offset + dtype.itemsize > point_step:
            raise ValueError(f"PointCloud2 field {k!r}: offset {field.offset} does not fit in point_step {point_step}")
        formats.append(dtype)
        offsets.append(int(field.offset))
    if height * width == 0:
        return np.zeros((0, 3))
    if row_step < width * point_step:
        raise ValueError(f"PointCloud2 row_step {row_step} is shorter than width {width} x point_step {point_step}")
    data = np.ascontiguousarray(np.asarray(msg.data, dtype=np.uint8)).reshape(-1)
    need = (height - 1) * row_step + width * point_step
    if data.size < need:
        raise ValueError(f"PointCloud2 data holds {data.size} bytes, its {height} x {width} points need {need}")
    record = np.dtype({"names": ["x", "y", "z"], "formats": formats, "offsets": offsets, "itemsize": point_step})
    points = np.ndarray((height, width), dtype=record, buffer=data, strides=(row_step, point_step))
    xyz = np.stack([points[k].reshape(-1).astype(np.float64) for k in ("x", "y", "z")], axis=-1)
    return np.ascontiguousarray(xyz[np.isfinite(xyz).all(axis=1)])


@dataclass(frozen=True)
class BagCloud:
    """One message's cloud: its index among the topic's messages (from 0), the bag's timestamp
    of it (ns) and the ``(N, 3)`` float64 points (possibly none)."""

    index: int
    timestamp: int
    points: np.ndarray


class BagClouds:
    """The PointCloud2 messages of one topic of a bag, every ``every``-th from the first.

    ``topic=None`` takes the bag's only PointCloud2 topic; several, none, or a ``topic`` that is
    not one of them: ValueError naming the bag and listing what it holds. ``len()`` is the number
    of clouds iterating yields."""

    def __init__(self, path: str | Path, topic: str | None = None, every: int = 1):
        self.path = Path(path)
        if not self.path.exists():
            raise ValueError(f"{str(self.path)!r}: no such file")
        if self.path.is_dir() and not (self.path / "metadata.yaml").is_file():
            raise ValueError(f"{str(self.path)!r}: a folder but not a ROS 2 bag (no metadata.yaml)")
        if int(every) != every or every < 1:
            raise ValueError(f"every={every!r}: must be a whole number >= 1")
        self.every = int(every)
        try:
            with self._reader() as reader:
                topics = {name: (info.msgtype, info.msgcount) for name, info in reader.topics.items()}
        except ValueError:
            raise
        except Exception as err:  # a truncated or foreign file: name it, not a parser trace
            raise self._error(err) from None
        clouds = {name: count for name, (msgtype, count) in topics.items() if msgtype == POINTCLOUD2}
        listing = ", ".join(f"{name} ({count} messages)" for name, count in clouds.items())
        if not clouds:
            held = ", ".join(f"{name} ({msgtype})" for name, (msgtype, _) in topics.items()) or "no topics"
            raise ValueError(f"{str(self.path)!r}: no {POINTCLOUD2} topic (the bag has {held})")
        if topic is None:
            if len(clouds) > 1:
                raise ValueError(f"{str(self.path)!r}: {len(clouds)} PointCloud2 topics, choose one (--topic): {listing}")
            topic = next(iter(clouds))
        elif topic not in clouds:
            raise ValueError(f"{str(self.path)!r}: no PointCloud2 topic {topic!r}; the bag's PointCloud2 topics: {listing}")
        self.topic = topic
        self.count = int(clouds[topic])

    def _reader(self):
        _need("rosbags")
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        # a ROS 2 bag may carry no message definitions: PointCloud2 is the same in every distribution
        return AnyReader([self.path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))

    def _error(self, err: BaseException, index: int | None = None) -> ValueError:
        where = "" if index is None else f" (message {index} on {self.topic})"
        return ValueError(f"{str(self.path)!r}: cannot read as a ROS bag{where} ({type(err).__name__}: {_first_line(err)})")

    def __len__(self) -> int:
        return math.ceil(self.count / self.every)

    def __iter__(self) -> Iterator[BagCloud]:
        index = -1
        try:
            with self._reader() as reader:
                connections = [c for c in reader.connections if c.topic == self.topic]
                for index, (connection, timestamp, raw) in enumerate(reader.messages(connections=connections)):
                    if index % self.every:
                        continue
                    msg = reader.deserialize(raw, connection.msgtype)
                    yield BagCloud(index, int(timestamp), pointcloud2_xyz(msg))
        except Exception as err:  # a message cut short or garbled, or a bad PointCloud2 layout
            raise self._error(err, max(index, 0)) from None
