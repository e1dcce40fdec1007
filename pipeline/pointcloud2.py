"""The ROS message codec shared by readers, writers and the simulator: sensor_msgs/PointCloud2 with numpy
(decode any message into columns, encode columns into a message), geometry_msgs/PoseStamped, and the CDR
serialisation of both. It depends on the vocabulary only, so sources and sinks meet here, not in each other.

Fields are read by name and datatype from the message, never by assumed offsets: a structured dtype is
built from the PointFields (offsets, `count`, `point_step` as itemsize, byte order) and laid over the
data with `np.frombuffer`, row by row when `row_step` carries padding.
"""

from __future__ import annotations

import struct
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import IntEnum, StrEnum
from typing import TYPE_CHECKING, Any, Final

import numpy as np

from aftershock.pipeline.types import Scan

if TYPE_CHECKING:
    from mcap.writer import Writer


class PointFieldType(IntEnum):
    """`sensor_msgs/PointField` datatypes."""

    INT8 = 1
    UINT8 = 2
    INT16 = 3
    UINT16 = 4
    INT32 = 5
    UINT32 = 6
    FLOAT32 = 7
    FLOAT64 = 8

    @property
    def numpy(self) -> np.dtype:
        return np.dtype(_NUMPY_OF[self])

    @staticmethod
    def of(dtype: np.dtype | type) -> PointFieldType:
        """The PointField datatype that holds a numpy dtype (bool as uint8, int64/uint64 refused)."""
        dt = np.dtype(dtype)
        if dt == np.bool_:
            return PointFieldType.UINT8
        for kind, name in _NUMPY_OF.items():
            if np.dtype(name) == dt.newbyteorder("="):
                return kind
        raise ValueError(f"PointCloud2 has no datatype for numpy {dt}")


_NUMPY_OF: Final[dict[PointFieldType, str]] = {
    PointFieldType.INT8: "i1",
    PointFieldType.UINT8: "u1",
    PointFieldType.INT16: "i2",
    PointFieldType.UINT16: "u2",
    PointFieldType.INT32: "i4",
    PointFieldType.UINT32: "u4",
    PointFieldType.FLOAT32: "f4",
    PointFieldType.FLOAT64: "f8",
}


class TimeConvention(StrEnum):
    """How a driver stores per-point time; the field name says which (see `TIME_FIELDS`)."""

    NS_OFFSET = "ns_offset"  # Ouster `t`, Livox `offset_time`: integer ns after the scan stamp
    S_OFFSET = "s_offset"  # Velodyne `time`: float seconds relative to the stamp
    S_ABSOLUTE = "s_absolute"  # `timestamp`: float seconds since the epoch (or relative, decided by value)


# Field names in order of preference, with their usual convention; integer fields are ns, float fields s.
TIME_FIELDS: Final[dict[str, TimeConvention]] = {
    "t": TimeConvention.NS_OFFSET,
    "offset_time": TimeConvention.NS_OFFSET,
    "time": TimeConvention.S_OFFSET,
    "time_offset": TimeConvention.S_OFFSET,
    "timestamp": TimeConvention.S_ABSOLUTE,
    "time_stamp": TimeConvention.S_ABSOLUTE,
    "stamp": TimeConvention.S_ABSOLUTE,
    "ts": TimeConvention.S_ABSOLUTE,
}
# A time value larger than this (about 11.6 days) cannot be an offset within one sweep: it is absolute.
_ABSOLUTE_THRESHOLD_S: Final[float] = 1e6

POINTFIELD_MSGDEF: Final[str] = """uint8 INT8=1
uint8 UINT8=2
uint8 INT16=3
uint8 UINT16=4
uint8 INT32=5
uint8 UINT32=6
uint8 FLOAT32=7
uint8 FLOAT64=8
string name
uint32 offset
uint8 datatype
uint32 count"""

MSGDEF_SEPARATOR: Final[str] = "=" * 80  # between a message definition and each type it uses
_HEADER_DEPS: Final[str] = f"""{MSGDEF_SEPARATOR}
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
{MSGDEF_SEPARATOR}
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec"""

# PointCloud2's own fields, the same in ROS 1 and ROS 2 (their Header differs).
POINTCLOUD2_FIELDS: Final[str] = """std_msgs/Header header
uint32 height
uint32 width
sensor_msgs/PointField[] fields
bool is_bigendian
uint32 point_step
uint32 row_step
uint8[] data
bool is_dense"""

POINTCLOUD2_MSGDEF: Final[str] = f"""{POINTCLOUD2_FIELDS}
{_HEADER_DEPS}
{MSGDEF_SEPARATOR}
MSG: sensor_msgs/PointField
{POINTFIELD_MSGDEF}
"""

POSE_STAMPED_MSGDEF: Final[str] = f"""std_msgs/Header header
geometry_msgs/Pose pose
{_HEADER_DEPS}
{MSGDEF_SEPARATOR}
MSG: geometry_msgs/Pose
geometry_msgs/Point position
geometry_msgs/Quaternion orientation
{MSGDEF_SEPARATOR}
MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
{MSGDEF_SEPARATOR}
MSG: geometry_msgs/Quaternion
float64 x
float64 y
float64 z
float64 w
"""


@dataclass(frozen=True, slots=True)
class Field:
    """One PointField, independent of how the message was decoded."""

    name: str
    offset: int
    datatype: PointFieldType
    count: int = 1


@dataclass(slots=True)
class Cloud:
    """A decoded PointCloud2: one array per field, (N,) or (N, count), native byte order, every point kept."""

    columns: dict[str, np.ndarray]
    height: int
    width: int
    fields: tuple[Field, ...]

    def __len__(self) -> int:
        return self.height * self.width


# --------------------------------------------------------------------------------------------- decoding


def fields_from_msg(fields: Sequence[Any]) -> tuple[Field, ...]:
    """PointFields from a decoded message (objects with name/offset/datatype/count attributes)."""
    out = []
    for f in fields:
        try:
            kind = PointFieldType(int(f.datatype))
        except ValueError:
            raise ValueError(f"field {f.name!r} has unknown PointField datatype {f.datatype}") from None
        out.append(Field(str(f.name), int(f.offset), kind, max(int(getattr(f, "count", 1) or 1), 1)))
    return tuple(out)


def structured_dtype(fields: Sequence[Field], point_step: int, big_endian: bool = False) -> np.dtype:
    """A numpy structured dtype laying the fields over one point of `point_step` bytes."""
    order = ">" if big_endian else "<"
    names, formats, offsets = [], [], []
    seen: set[str] = set()
    for f in fields:
        if f.name in seen:  # the first is used, as PCL does; said once per field name and run
            warnings.warn(f"PointCloud2 field {f.name!r} is declared more than once; the first is used", stacklevel=2)
            continue
        if not f.name:  # some drivers pad with unnamed fields
            continue
        seen.add(f.name)
        base = np.dtype(order + _NUMPY_OF[f.datatype])
        end = f.offset + base.itemsize * f.count
        if end > point_step:
            raise ValueError(f"field {f.name!r} ends at byte {end}, beyond point_step {point_step}")
        names.append(f.name)
        formats.append(base if f.count == 1 else (base, (f.count,)))
        offsets.append(f.offset)
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step})


def decode_records(
    data: bytes | memoryview | np.ndarray,
    fields: Sequence[Field],
    *,
    height: int,
    width: int,
    point_step: int,
    row_step: int,
    big_endian: bool = False,
) -> np.ndarray:
    """The point records of a PointCloud2 as a flat structured array, zero-copy when rows are unpadded."""
    if point_step <= 0:
        raise ValueError(f"point_step is {point_step}")
    dtype = structured_dtype(fields, point_step, big_endian)
    buf = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data.view(np.uint8)
    row_bytes = width * point_step
    if row_step < row_bytes and height > 1:
        raise ValueError(f"row_step {row_step} is shorter than width * point_step = {row_bytes}")
    row_step = max(row_step, row_bytes)
    needed = (height - 1) * row_step + row_bytes if height > 0 else 0
    if len(buf) < needed:
        raise ValueError(f"data holds {len(buf)} bytes, {needed} needed for {height} x {width} points")
    if height == 0 or width == 0:
        return np.zeros(0, dtype=dtype)
    if row_step == row_bytes or height == 1:
        return buf[: height * row_bytes].view(dtype)
    # Padded rows: a strided view over the row starts, then the valid bytes of each row.
    rows = np.lib.stride_tricks.as_strided(buf, shape=(height, row_bytes), strides=(row_step, 1))
    return np.ascontiguousarray(rows).reshape(-1).view(dtype)


def records_to_columns(records: np.ndarray) -> dict[str, np.ndarray]:
    """Per-field arrays in native byte order (copies, so the message buffer can be released)."""
    cols: dict[str, np.ndarray] = {}
    for name in records.dtype.names or ():
        arr = records[name]
        cols[name] = np.ascontiguousarray(arr, dtype=arr.dtype.newbyteorder("="))
    return cols


def decode_pointcloud2(msg: Any) -> Cloud:
    """Decode a PointCloud2 message object (ROS 1 or ROS 2 decoder output) into columns."""
    fields = fields_from_msg(msg.fields)
    records = decode_records(
        msg.data,
        fields,
        height=int(msg.height),
        width=int(msg.width),
        point_step=int(msg.point_step),
        row_step=int(msg.row_step),
        big_endian=bool(msg.is_bigendian),
    )
    return Cloud(records_to_columns(records), int(msg.height), int(msg.width), fields)


def header_stamp_ns(msg: Any) -> int:
    """The header stamp of a ROS message in ns (0 when unset)."""
    return stamp_to_ns(msg.header.stamp)


# ---------------------------------------------------------------------------------- columns -> Scan parts


def find_time_field(names: Sequence[str]) -> str | None:
    """The per-point time field among `names`, by the names drivers use (case-insensitive)."""
    lower = {n.lower(): n for n in names}
    for candidate in TIME_FIELDS:
        if candidate in lower:
            return lower[candidate]
    return None


def times_relative_s(values: np.ndarray, name: str, stamp_ns: int) -> np.ndarray:
    """Per-point times in seconds relative to the scan stamp, whatever the driver's convention.

    Integer fields are nanoseconds, float fields seconds. A value beyond a sweep's plausible length
    (`_ABSOLUTE_THRESHOLD_S`) is an absolute time and gets the stamp subtracted.
    """
    values = np.asarray(values).reshape(len(values), -1)[:, 0]
    if values.dtype.kind in "iu":
        ns = values.astype(np.int64)
        if len(ns) and np.abs(ns).max() > _ABSOLUTE_THRESHOLD_S * 1e9:
            ns = ns - np.int64(stamp_ns)
        return ns.astype(np.float64) * 1e-9
    s = values.astype(np.float64)
    finite = s[np.isfinite(s)]
    if len(finite) and np.abs(finite).max() > _ABSOLUTE_THRESHOLD_S:
        # Subtract in two parts so float64 keeps sub-microsecond precision.
        sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
        s = (s - sec) - nsec * 1e-9
    return s


def unpack_rgb(values: np.ndarray) -> np.ndarray:
    """Colours from a packed `rgb`/`rgba` field (float32 or uint32 holding 0x00RRGGBB) as (N, 3) uint8."""
    raw = np.ascontiguousarray(values).reshape(len(values), -1)[:, 0]
    if raw.dtype.itemsize != 4:
        raw = raw.astype(np.uint32)
    packed = raw.view(np.uint32)
    return np.stack([(packed >> 16) & 0xFF, (packed >> 8) & 0xFF, packed & 0xFF], axis=1).astype(np.uint8)


def colors_from_columns(cols: Mapping[str, np.ndarray]) -> np.ndarray | None:
    """(N, 3) uint8 colours from packed `rgb`/`rgba` or separate `r g b` / `red green blue` fields."""
    lower = {k.lower(): k for k in cols}
    for packed in ("rgb", "rgba"):
        if packed in lower:
            return unpack_rgb(cols[lower[packed]])
    for names in (("r", "g", "b"), ("red", "green", "blue")):
        if all(n in lower for n in names):
            chans = [np.asarray(cols[lower[n]]).reshape(-1) for n in names]
            if any(c.dtype.kind == "f" for c in chans) and max(float(c.max(initial=0)) for c in chans) <= 1.0:
                chans = [c * 255.0 for c in chans]
            return np.clip(np.stack(chans, axis=1), 0, 255).astype(np.uint8)
    return None


def valid_mask(xyz: np.ndarray) -> np.ndarray:
    """Points that are real returns: finite and not all-zero."""
    return np.isfinite(xyz).all(axis=1) & np.any(xyz != 0, axis=1)


INTENSITY_FIELDS: Final[tuple[str, ...]] = ("intensity", "i", "signal", "reflectivity")
RING_FIELDS: Final[tuple[str, ...]] = ("ring", "channel", "line", "laser_id")
CLASS_FIELD: Final[str] = "class_id"
INSTANCE_FIELD: Final[str] = "instance_id"


class NoXYZError(ValueError):
    """The cloud has no x, y and z fields."""


def _first_component(a: np.ndarray) -> np.ndarray:
    return a if a.ndim == 1 else a.reshape(len(a), -1)[:, 0]


def _pick(cols: Mapping[str, np.ndarray], names: Sequence[str]) -> np.ndarray | None:
    lower = {k.lower(): k for k in cols}
    for n in names:
        if n in lower:
            return _first_component(cols[lower[n]])
    return None


def stamp_to_ns(stamp: Any) -> int:
    """Nanoseconds of a ROS 1 / ROS 2 / rosbags / protobuf time object."""
    if hasattr(stamp, "to_nsec"):
        return int(stamp.to_nsec())
    if hasattr(stamp, "nanosec"):
        return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    if hasattr(stamp, "nsecs"):
        return int(stamp.secs) * 1_000_000_000 + int(stamp.nsecs)
    if hasattr(stamp, "nanos"):
        return int(stamp.seconds) * 1_000_000_000 + int(stamp.nanos)
    return int(stamp)


def columns_to_scan(
    cols: Mapping[str, np.ndarray],
    *,
    stamp_ns: int,
    seq: int = 0,
    frame_id: str = "",
    topic: str = "",
    log_time_ns: int | None = None,
) -> Scan | None:
    """A `Scan` of the valid points of decoded columns, every per-point array filtered alike; None if none is valid.

    Raises `NoXYZError` when the cloud has no x/y/z.
    """
    lower = {k.lower(): k for k in cols}
    if not all(a in lower for a in ("x", "y", "z")):
        raise NoXYZError(f"point cloud has no x/y/z fields (fields: {', '.join(cols) or 'none'})")
    xyz = np.stack([_first_component(cols[lower[a]]) for a in ("x", "y", "z")], axis=1).astype(np.float64)
    keep = valid_mask(xyz)
    if not keep.any():
        return None
    everything = bool(keep.all())

    def sel(a: np.ndarray | None, dtype: Any) -> np.ndarray | None:
        if a is None:
            return None
        a = a if everything else a[keep]
        return a.astype(dtype, copy=False)

    time_name = find_time_field(list(cols))
    times = None
    if time_name is not None:
        raw = _first_component(cols[time_name])
        times = times_relative_s(raw if everything else raw[keep], time_name, stamp_ns)
    colors = colors_from_columns(cols)
    return Scan(
        stamp_ns=int(stamp_ns),
        points=xyz if everything else xyz[keep],
        seq=seq,
        frame_id=frame_id,
        intensity=sel(_pick(cols, INTENSITY_FIELDS), np.float32),
        colors=sel(colors, np.uint8),
        times=times,
        ring=sel(_pick(cols, RING_FIELDS), np.uint16),
        class_ids=sel(_pick(cols, (CLASS_FIELD,)), np.uint16),
        instance_ids=sel(_pick(cols, (INSTANCE_FIELD,)), np.uint32),
        log_time_ns=log_time_ns,
        topic=topic,
    )


# --------------------------------------------------------------------------------------------- encoding


def encode_pointcloud2(
    columns: dict[str, np.ndarray],
    *,
    stamp_ns: int,
    frame_id: str,
    height: int = 1,
    big_endian: bool = False,
    point_step: int | None = None,
    row_padding: int = 0,
) -> dict:
    """A `sensor_msgs/msg/PointCloud2` dict (for `mcap_ros2.writer.Writer.write_message`) from named columns.

    Each column is (N,) or (N, count); its dtype picks the PointField datatype. Fields are packed in the
    order given; `point_step` larger than the packed size and `row_padding` bytes after each row produce
    the padding some drivers emit. N must be a multiple of `height` (organized clouds: row-major).
    """
    if not columns:
        raise ValueError("no columns to encode")
    arrays = {name: np.asarray(a) for name, a in columns.items()}
    n = len(next(iter(arrays.values())))
    if any(len(a) != n for a in arrays.values()):
        raise ValueError("columns differ in length")
    if height < 1 or n % height:
        raise ValueError(f"{n} points do not fill {height} rows")
    width = n // height
    order = ">" if big_endian else "<"
    fields, names, formats, offsets = [], [], [], []
    offset = 0
    for name, arr in arrays.items():
        kind = PointFieldType.of(arr.dtype)
        count = 1 if arr.ndim == 1 else int(np.prod(arr.shape[1:]))
        base = np.dtype(order + _NUMPY_OF[kind])
        fields.append({"name": name, "offset": offset, "datatype": int(kind), "count": count})
        names.append(name)
        formats.append(base if count == 1 else (base, (count,)))
        offsets.append(offset)
        offset += base.itemsize * count
    step = offset if point_step is None else point_step
    if step < offset:
        raise ValueError(f"point_step {step} is smaller than the {offset} bytes of the fields")
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    records = np.zeros(n, dtype=dtype)
    for name, arr in arrays.items():
        records[name] = arr.reshape(records[name].shape)
    row_bytes = width * step
    row_step = row_bytes + row_padding
    if row_padding:
        padded = np.zeros((height, row_step), dtype=np.uint8)
        padded[:, :row_bytes] = records.view(np.uint8).reshape(height, row_bytes)
        data = padded.tobytes()
    else:
        data = records.tobytes()
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    xyz = [arrays[k] for k in ("x", "y", "z") if k in arrays]
    dense = len(xyz) == 3 and bool(np.all(np.isfinite(np.stack([a.astype(np.float64) for a in xyz]))))
    return {
        "header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame_id},
        "height": height,
        "width": width,
        "fields": fields,
        "is_bigendian": big_endian,
        "point_step": step,
        "row_step": row_step,
        "data": data,
        "is_dense": dense,
    }


def matrix_to_quaternion(r: np.ndarray) -> np.ndarray:
    """(x, y, z, w) unit quaternion of a 3 x 3 rotation matrix."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(r, dtype=np.float64)[:3, :3]).as_quat()


def quaternion_to_matrix(q: Sequence[float]) -> np.ndarray:
    """3 x 3 rotation of an (x, y, z, w) quaternion (normalised first)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(np.asarray(q, dtype=np.float64)).as_matrix()


def pose_stamped_message(matrix: np.ndarray, stamp_ns: int, frame_id: str = "map") -> dict:
    """A `geometry_msgs/msg/PoseStamped` dict for a 4 x 4 pose (sensor -> world)."""
    m = np.asarray(matrix, dtype=np.float64)
    qx, qy, qz, qw = (float(v) for v in matrix_to_quaternion(m[:3, :3]))
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return {
        "header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame_id},
        "pose": {
            "position": {"x": float(m[0, 3]), "y": float(m[1, 3]), "z": float(m[2, 3])},
            "orientation": {"x": qx, "y": qy, "z": qz, "w": qw},
        },
    }


def pose_to_matrix(pose: Any) -> np.ndarray:
    """4 x 4 matrix from a decoded `geometry_msgs/Pose` (attributes position / orientation); ValueError for
    a pose that is none: a non-finite position, or a quaternion that is zero or not finite."""
    p, o = pose.position, pose.orientation
    q = np.array([o.x, o.y, o.z, o.w], dtype=np.float64)
    t = np.array([p.x, p.y, p.z], dtype=np.float64)
    if not (np.isfinite(q).all() and np.isfinite(t).all()):
        raise ValueError(f"the pose is not finite (position {t.tolist()}, orientation {q.tolist()})")
    if np.linalg.norm(q) < 1e-6:
        raise ValueError("the pose's quaternion is zero, so it is no rotation")
    m = np.eye(4)
    m[:3, :3] = quaternion_to_matrix([o.x, o.y, o.z, o.w])
    m[:3, 3] = [p.x, p.y, p.z]
    return m


# --------------------------------------------------------------------------------------------- fast CDR


class _Cdr:
    """Little-endian CDR writer for the few types we emit (alignment counted after the 4-byte header)."""

    def __init__(self) -> None:
        self.parts: list[bytes] = [b"\x00\x01\x00\x00"]
        self.size = 0

    def _align(self, n: int) -> None:
        pad = (-self.size) % n
        if pad:
            self.parts.append(b"\x00" * pad)
            self.size += pad

    def put(self, fmt: str, *values: Any) -> None:
        size = struct.calcsize("<" + fmt)
        self._align(min(size, 8) if len(fmt) == 1 else 1)
        self.parts.append(struct.pack("<" + fmt, *values))
        self.size += size

    def string(self, s: str) -> None:
        b = s.encode()
        self.put("I", len(b) + 1)
        self.parts.append(b + b"\x00")
        self.size += len(b) + 1

    def raw(self, b: bytes) -> None:
        self.parts.append(b)
        self.size += len(b)

    def header(self, h: Mapping[str, Any]) -> None:
        self.put("i", int(h["stamp"]["sec"]))
        self.put("I", int(h["stamp"]["nanosec"]))
        self.string(str(h["frame_id"]))

    def bytes(self) -> bytes:
        return b"".join(self.parts)


def serialize_pointcloud2(msg: Mapping[str, Any]) -> bytes:
    """CDR bytes of a PointCloud2 dict from `encode_pointcloud2` (byte-identical to mcap_ros2's serializer).

    For writers that use the plain `mcap.writer.Writer.add_message` (schema `POINTCLOUD2_MSGDEF`,
    message encoding `cdr`), e.g. to mix ROS 2 and other channels in one file.
    """
    w = _Cdr()
    w.header(msg["header"])
    w.put("I", int(msg["height"]))
    w.put("I", int(msg["width"]))
    w.put("I", len(msg["fields"]))
    for f in msg["fields"]:
        w.string(str(f["name"]))
        w.put("I", int(f["offset"]))
        w.put("B", int(f["datatype"]))
        w.put("I", int(f["count"]))
    w.put("?", bool(msg["is_bigendian"]))
    w.put("I", int(msg["point_step"]))
    w.put("I", int(msg["row_step"]))
    data = bytes(msg["data"])
    w.put("I", len(data))
    w.raw(data)
    w.put("?", bool(msg["is_dense"]))
    return w.bytes()


def register_cloud_and_pose(writer: Writer, points_topic: str, pose_topic: str) -> tuple[int, int]:
    """The channels of a ROS 2 MCAP for PointCloud2 scans and PoseStamped poses (CDR): their ids, in that order."""
    cloud = writer.register_schema("sensor_msgs/msg/PointCloud2", "ros2msg", POINTCLOUD2_MSGDEF.encode())
    pose = writer.register_schema("geometry_msgs/msg/PoseStamped", "ros2msg", POSE_STAMPED_MSGDEF.encode())
    return writer.register_channel(points_topic, "cdr", cloud), writer.register_channel(pose_topic, "cdr", pose)


def serialize_pose_stamped(msg: Mapping[str, Any]) -> bytes:
    """CDR bytes of a PoseStamped dict from `pose_stamped_message`."""
    w = _Cdr()
    w.header(msg["header"])
    p, o = msg["pose"]["position"], msg["pose"]["orientation"]
    for v in (p["x"], p["y"], p["z"], o["x"], o["y"], o["z"], o["w"]):
        w.put("d", float(v))
    return w.bytes()
