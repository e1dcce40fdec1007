"""Scans from ROS bags — ROS 1 `.bag` files and ROS 2 bag folders (sqlite3 or mcap storage) — via rosbags."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Final

import numpy as np

from aftershock.pipeline.errors import InputError
from aftershock.pipeline.pointcloud2 import decode_pointcloud2, header_stamp_ns, pose_to_matrix
from aftershock.pipeline.types import Scan
from aftershock.sources.common import (
    CloudMessage,
    Damage,
    DecodedCloud,
    Event,
    ReadOptions,
    assemble,
    choose_pose_topic,
    choose_topic,
    pose_event,
)

ROS1_MAGIC: Final[bytes] = b"#ROSBAG V2.0"


def is_ros1_bag(path: Path) -> bool:
    with path.open("rb") as fh:
        return fh.read(len(ROS1_MAGIC)) == ROS1_MAGIC


def is_ros2_bag(path: Path) -> bool:
    return path.is_dir() and (path / "metadata.yaml").is_file()


def _reader(path: Path) -> Any:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from aftershock.sources.inflate import bound_rosbags

    bound_rosbags()
    return AnyReader([path], default_typestore=get_typestore(Stores.LATEST))


def _errors() -> tuple[type[BaseException], ...]:
    from rosbags.highlevel import AnyReaderError

    errs: list[type[BaseException]] = [AnyReaderError, EOFError, ValueError, KeyError, IndexError, OSError]
    try:
        from rosbags.rosbag1 import ReaderError as Ros1Error
        from rosbags.rosbag2 import ReaderError as Ros2Error

        errs += [Ros1Error, Ros2Error]
    except ImportError:  # pragma: no cover
        pass
    return tuple(errs)


def _first_line(exc: BaseException) -> str:
    """An exception as `Type: its first line` (a YAML parser's message spans several, with a caret drawing)."""
    text = str(exc).strip().splitlines()[0].rstrip(":") if str(exc).strip() else ""
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


@dataclass(slots=True)
class BagCatalog:
    path: Path
    topics: dict[str, tuple[str, int]] = field(default_factory=dict)  # topic -> (type, count)
    start_ns: int | None = None
    end_ns: int | None = None

    @property
    def types(self) -> dict[str, str]:
        return {t: ty for t, (ty, _) in self.topics.items()}

    @property
    def duration_s(self) -> float:
        return 0.0 if self.start_ns is None or self.end_ns is None else (self.end_ns - self.start_ns) * 1e-9


def read_catalog(path: Path) -> BagCatalog:
    """Topics, types, counts and span of a bag; InputError if rosbags cannot open it."""
    cat = BagCatalog(path)
    try:
        with _reader(path) as reader:
            for name, info in reader.topics.items():
                # rosbags names every type the ROS 2 way (pkg/msg/Name), ROS 1 bags too
                cat.topics[name] = (info.msgtype or "", int(info.msgcount or 0))
            if reader.message_count:
                cat.start_ns, cat.end_ns = int(reader.start_time), int(reader.end_time)
    except _errors() as exc:
        raise InputError(f"cannot open the ROS bag ({_first_line(exc)})", path) from None
    return cat


def events(
    path: Path, cloud_topics: set[str], pose_topic: str | None = None, lo: int | None = None, hi: int | None = None
) -> Iterator[Event]:
    """Cloud (lazily decoded), pose and damage events of the given topics in log-time order."""
    errors = _errors()
    try:
        with _reader(path) as reader:
            wanted = cloud_topics | ({pose_topic} if pose_topic else set())
            conns = [c for c in reader.connections if c.topic in wanted]
            for conn, log_time, raw in reader.messages(connections=conns, start=lo, stop=hi):
                if conn.topic in cloud_topics:
                    decode = partial(_cloud, reader, raw, conn.msgtype)
                    yield CloudMessage(int(log_time), conn.topic, decode)
                else:
                    yield pose_event(int(log_time), conn.topic, partial(_pose, reader, raw, conn.msgtype))
    except errors as exc:
        yield Damage(f"the bag is cut off or damaged ({_first_line(exc)})")


def _pose(reader: Any, raw: bytes, msgtype: str) -> tuple[int, np.ndarray]:
    msg = reader.deserialize(raw, msgtype)
    return header_stamp_ns(msg), pose_to_matrix(msg.pose)


def _cloud(reader: Any, raw: bytes, msgtype: str) -> DecodedCloud:
    msg = reader.deserialize(raw, msgtype)
    cloud = decode_pointcloud2(msg)
    return DecodedCloud(cloud.columns, header_stamp_ns(msg), str(msg.header.frame_id), cloud.fields, cloud.height)


def open_bag(path: Path, options: ReadOptions) -> Iterator[Scan]:
    """Scans of one PointCloud2 topic of a ROS 1 or ROS 2 bag (checked now, read lazily)."""
    cat = read_catalog(path)
    chosen = choose_topic(cat.types, options.topic, path)
    if cat.types[chosen] == "foxglove.PointCloud":
        raise InputError(f"topic {chosen}: foxglove.PointCloud is read from MCAP files only", path)
    pose = choose_pose_topic(cat.types, options.pose_topic, path)
    lo, hi = options.window_ns(cat.start_ns)
    total = cat.topics[chosen][1] if lo is None and hi is None else None
    return assemble(
        events(path, {chosen}, pose, lo, hi), options, path=path, topic=chosen, with_poses=pose is not None, total=total
    )
