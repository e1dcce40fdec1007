"""Small synthetic logs for tests: MCAP in ROS 2, ROS 1 and foxglove encodings, ROS bags, damaged files.

Every writer takes a list of column dicts (name -> (N,) or (N, k) array, the dtype picks the PointField
datatype) so a test knows exactly what the reader must give back.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Final

import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from aftershock.pipeline.pointcloud2 import (
    MSGDEF_SEPARATOR,
    POINTCLOUD2_FIELDS,
    POINTCLOUD2_MSGDEF,
    POINTFIELD_MSGDEF,
    POSE_STAMPED_MSGDEF,
    encode_pointcloud2,
    pose_stamped_message,
)

T0_NS: Final[int] = 1_700_000_000_000_000_000
PERIOD_NS: Final[int] = 100_000_000
Columns = Mapping[str, np.ndarray]

# The ROS 1 definition as a ROS 1 recorder stores it (Header with seq, `time` stamp).
ROS1_POINTCLOUD2_MSGDEF: Final[str] = f"""{POINTCLOUD2_FIELDS}
{MSGDEF_SEPARATOR}
MSG: std_msgs/Header
uint32 seq
time stamp
string frame_id
{MSGDEF_SEPARATOR}
MSG: sensor_msgs/PointField
{POINTFIELD_MSGDEF}
"""


# --------------------------------------------------------------------------------------------- columns


def xyz_columns(n: int, seed: int = 0, dtype: type = np.float32) -> dict[str, np.ndarray]:
    """Random points 1-10 m away, per-point Ouster-style `t` (u32 ns over a 0.1 s sweep) and intensity."""
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    pts = direction * rng.uniform(1.0, 10.0, size=(n, 1))
    return {
        "x": pts[:, 0].astype(dtype),
        "y": pts[:, 1].astype(dtype),
        "z": pts[:, 2].astype(dtype),
        "intensity": rng.uniform(0, 255, n).astype(np.float32),
        "t": np.linspace(0, 99_000_000, n).astype(np.uint32),
    }


def every_datatype_columns(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    """x y z in float64 plus one field of every PointField datatype, one with count 3."""
    rng = np.random.default_rng(seed)
    cols = xyz_columns(n, seed, np.float64)
    del cols["t"]
    cols |= {
        "i8": rng.integers(-128, 127, n).astype(np.int8),
        "u8": rng.integers(0, 255, n).astype(np.uint8),
        "i16": rng.integers(-30000, 30000, n).astype(np.int16),
        "u16": rng.integers(0, 60000, n).astype(np.uint16),
        "i32": rng.integers(-(2**31), 2**31 - 1, n).astype(np.int32),
        "u32": rng.integers(0, 2**32 - 1, n, dtype=np.uint64).astype(np.uint32),
        "f32": rng.normal(size=n).astype(np.float32),
        "f64": rng.normal(size=n).astype(np.float64),
        "normal": rng.normal(size=(n, 3)).astype(np.float32),
        "class_id": rng.integers(0, 14, n).astype(np.uint16),
        "instance_id": rng.integers(0, 50, n).astype(np.uint32),
    }
    return cols


def organized_columns(height: int, width: int, zero_rows: Sequence[int], nan_points: int = 0, seed: int = 0) -> dict:
    """An organized cloud (row-major) whose rows in `zero_rows` are all-zero, plus a few NaN points."""
    cols = xyz_columns(height * width, seed)
    for r in zero_rows:
        for k in ("x", "y", "z"):
            cols[k][r * width : (r + 1) * width] = 0.0
    if nan_points:
        idx = np.random.default_rng(seed + 1).choice(height * width, nan_points, replace=False)
        cols["x"][idx] = np.nan
    return cols


# --------------------------------------------------------------------------------------------- MCAP writers


def write_ros2_mcap(
    path: Path,
    clouds: Sequence[Columns],
    *,
    topic: str = "/points",
    frame_id: str = "lidar",
    t0_ns: int = T0_NS,
    height: int = 1,
    big_endian: bool = False,
    point_step: int | None = None,
    row_padding: int = 0,
    poses: Sequence[np.ndarray] | None = None,
    pose_topic: str = "/ground_truth/pose",
    pose_offset_ns: int = 0,
    chunk_size: int = 1 << 20,
    compression: CompressionType = CompressionType.ZSTD,
    extra_cloud_topic: str | None = None,
    zero_header_stamp: bool = False,
) -> Path:
    """A ROS 2 MCAP: one PointCloud2 per entry of `clouds` every PERIOD_NS, optional PoseStamped poses."""
    from mcap_ros2.writer import Writer

    with path.open("wb") as fh:
        w = Writer(fh, chunk_size=chunk_size, compression=compression)
        schema = w.register_msgdef("sensor_msgs/msg/PointCloud2", POINTCLOUD2_MSGDEF)
        pose_schema = w.register_msgdef("geometry_msgs/msg/PoseStamped", POSE_STAMPED_MSGDEF) if poses else None
        for k, cols in enumerate(clouds):
            t = t0_ns + k * PERIOD_NS
            msg = encode_pointcloud2(
                dict(cols),
                stamp_ns=0 if zero_header_stamp else t,
                frame_id=frame_id,
                height=height,
                big_endian=big_endian,
                point_step=point_step,
                row_padding=row_padding,
            )
            w.write_message(topic, schema, msg, log_time=t, publish_time=t)
            if extra_cloud_topic:
                w.write_message(extra_cloud_topic, schema, msg, log_time=t, publish_time=t)
            if poses is not None and pose_schema is not None:
                tp = t + pose_offset_ns
                w.write_message(pose_topic, pose_schema, pose_stamped_message(poses[k], tp), log_time=tp)
        w.finish()
    return path


def _ros1_pointcloud2(cols: Columns, stamp_ns: int, frame_id: str, height: int, seq: int) -> bytes:
    msg = encode_pointcloud2(dict(cols), stamp_ns=stamp_ns, frame_id=frame_id, height=height)
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    frame = frame_id.encode()
    parts = [np.array([seq, sec, nsec, len(frame)], "<u4").tobytes(), frame]
    parts.append(np.array([msg["height"], msg["width"], len(msg["fields"])], "<u4").tobytes())
    for f in msg["fields"]:
        name = f["name"].encode()
        parts += [np.array([len(name)], "<u4").tobytes(), name, np.array([f["offset"]], "<u4").tobytes()]
        parts += [bytes([f["datatype"]]), np.array([f["count"]], "<u4").tobytes()]
    parts += [
        bytes([msg["is_bigendian"]]),
        np.array([msg["point_step"], msg["row_step"], len(msg["data"])], "<u4").tobytes(),
    ]
    parts += [msg["data"], bytes([msg["is_dense"]])]
    return b"".join(parts)


def write_ros1_mcap(
    path: Path, clouds: Sequence[Columns], *, topic: str = "/points", frame_id: str = "lidar", height: int = 1
) -> Path:
    """An MCAP in ROS 1 encoding (profile ros1, schema `sensor_msgs/PointCloud2`, encoding ros1), plus a text topic."""
    with path.open("wb") as fh:
        w = McapWriter(fh)
        w.start(profile="ros1", library="aftershock-tests")
        sid = w.register_schema("sensor_msgs/PointCloud2", "ros1msg", ROS1_POINTCLOUD2_MSGDEF.encode())
        cid = w.register_channel(topic, "ros1", sid)
        log_sid = w.register_schema("std_msgs/String", "ros1msg", b"string data")
        log_cid = w.register_channel("/chatter", "ros1", log_sid)
        for k, cols in enumerate(clouds):
            t = T0_NS + k * PERIOD_NS
            w.add_message(cid, log_time=t, data=_ros1_pointcloud2(cols, t, frame_id, height, k), publish_time=t)
            text = b"hello"
            w.add_message(log_cid, log_time=t, data=np.array([len(text)], "<u4").tobytes() + text, publish_time=t)
        w.finish()
    return path


def write_foxglove_mcap(
    path: Path, clouds: Sequence[Columns], *, topic: str = "/points", frame_id: str = "lidar"
) -> Path:
    """An MCAP of `foxglove.PointCloud` protobuf messages."""
    from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
    from mcap_protobuf.writer import Writer

    from aftershock.pipeline.pointcloud2 import PointFieldType
    from aftershock.sources.foxglove import POINTFIELD_TO_FOXGLOVE

    with path.open("wb") as fh:
        w = Writer(fh)
        for k, cols in enumerate(clouds):
            t = T0_NS + k * PERIOD_NS
            msg = encode_pointcloud2(dict(cols), stamp_ns=t, frame_id=frame_id)
            pc = PointCloud(frame_id=frame_id, point_stride=msg["point_step"], data=msg["data"])
            pc.timestamp.FromNanoseconds(t)
            pc.pose.orientation.w = 1.0
            for f in msg["fields"]:
                if f["count"] != 1:
                    raise ValueError("foxglove.PointCloud fields have no count")
                kind = POINTFIELD_TO_FOXGLOVE[PointFieldType(f["datatype"])]
                pc.fields.append(PackedElementField(name=f["name"], offset=f["offset"], type=kind))
            w.write_message(topic, pc, log_time=t, publish_time=t)
        w.finish()
    return path


def write_string_mcap(path: Path) -> Path:
    """A valid ROS 2 MCAP with no point-cloud topic."""
    from mcap_ros2.writer import Writer

    with path.open("wb") as fh:
        w = Writer(fh)
        schema = w.register_msgdef("std_msgs/msg/String", "string data")
        for k in range(3):
            w.write_message("/chatter", schema, {"data": f"hello {k}"}, log_time=T0_NS + k * PERIOD_NS)
        w.finish()
    return path


def chunk_offsets(path: Path) -> list[tuple[int, int]]:
    """(start, length) of every chunk record, from the file's summary."""
    with path.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    return sorted((c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes)


def truncate_in_chunk(src: Path, dst: Path, chunk: int) -> int:
    """Copy `src` cut off in the middle of its `chunk`-th chunk; returns the cut offset."""
    start, length = chunk_offsets(src)[chunk]
    cut = start + length // 2
    dst.write_bytes(src.read_bytes()[:cut])
    return cut


# --------------------------------------------------------------------------------------------- bags


def _rosbags_cloud(ts, cols: Columns, stamp_ns: int, frame_id: str, height: int = 1):
    msg = encode_pointcloud2(dict(cols), stamp_ns=stamp_ns, frame_id=frame_id, height=height)
    t = ts.types
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    header = t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=frame_id)
    fields = [t["sensor_msgs/msg/PointField"](**f) for f in msg["fields"]]
    return t["sensor_msgs/msg/PointCloud2"](
        header=header,
        height=msg["height"],
        width=msg["width"],
        fields=fields,
        is_bigendian=msg["is_bigendian"],
        point_step=msg["point_step"],
        row_step=msg["row_step"],
        data=np.frombuffer(msg["data"], np.uint8),
        is_dense=msg["is_dense"],
    )


def write_bag(
    path: Path, clouds: Sequence[Columns], *, ros2: bool, topic: str = "/points", frame_id: str = "lidar"
) -> Path:
    """A ROS 1 `.bag` file or a ROS 2 bag folder (sqlite3) of PointCloud2 messages, via rosbags."""
    from rosbags.typesys import Stores, get_typestore

    msgtype = "sensor_msgs/msg/PointCloud2"
    ts = get_typestore(Stores.LATEST)
    if ros2:
        from rosbags.rosbag2 import Writer as Ros2Writer

        with Ros2Writer(path, version=9) as w:
            conn = w.add_connection(topic, msgtype, typestore=ts)
            for k, cols in enumerate(clouds):
                t = T0_NS + k * PERIOD_NS
                w.write(conn, t, ts.serialize_cdr(_rosbags_cloud(ts, cols, t, frame_id), msgtype))
    else:
        from rosbags.rosbag1 import Writer as Ros1Writer

        with Ros1Writer(path) as w:
            conn = w.add_connection(topic, msgtype, typestore=ts)
            for k, cols in enumerate(clouds):
                t = T0_NS + k * PERIOD_NS
                w.write(conn, t, ts.serialize_ros1(_rosbags_cloud(ts, cols, t, frame_id), msgtype))
    return path


def interruptible() -> None:
    """`preexec_fn` for a child the test will Ctrl-C: a shell's background job inherits SIGINT ignored, and a
    Python child started so never raises KeyboardInterrupt; give it the default disposition back."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)
