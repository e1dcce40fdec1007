"""`foxglove.PointCloud` (protobuf) into the same columns as a PointCloud2.

Foxglove's PackedElementField numbers its types differently from ROS's PointField; the data is
little-endian, unorganized, `point_stride` bytes per point. The cloud's `pose` (its origin in
`frame_id`) is not applied: points stay in the cloud's own frame, like a driver's PointCloud2.
"""

from __future__ import annotations

from typing import Any, Final

from aftershock.pipeline.pointcloud2 import Field, PointFieldType, decode_records, records_to_columns, stamp_to_ns
from aftershock.sources.common import DecodedCloud

# foxglove.PackedElementField.NumericType -> sensor_msgs/PointField datatype
FOXGLOVE_TYPES: Final[dict[int, PointFieldType]] = {
    1: PointFieldType.UINT8,
    2: PointFieldType.INT8,
    3: PointFieldType.UINT16,
    4: PointFieldType.INT16,
    5: PointFieldType.UINT32,
    6: PointFieldType.INT32,
    7: PointFieldType.FLOAT32,
    8: PointFieldType.FLOAT64,
}
POINTFIELD_TO_FOXGLOVE: Final[dict[PointFieldType, int]] = {v: k for k, v in FOXGLOVE_TYPES.items()}


def decode_foxglove_pointcloud(msg: Any) -> DecodedCloud:
    """Columns of a decoded `foxglove.PointCloud` protobuf message."""
    fields = []
    for f in msg.fields:
        if int(f.type) not in FOXGLOVE_TYPES:
            raise ValueError(f"field {f.name!r} has unknown foxglove numeric type {f.type}")
        fields.append(Field(f.name, int(f.offset), FOXGLOVE_TYPES[int(f.type)]))
    stride = int(msg.point_stride)
    data = bytes(msg.data)
    n = len(data) // stride if stride else 0
    records = decode_records(data, fields, height=1, width=n, point_step=stride, row_step=n * stride)
    return DecodedCloud(records_to_columns(records), stamp_to_ns(msg.timestamp), str(msg.frame_id), tuple(fields))
