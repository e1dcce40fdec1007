"""The numpy PointCloud2 codec: every datatype, count, padding, byte order, organized clouds, invalid rows."""

from __future__ import annotations

import io
from types import SimpleNamespace

import numpy as np
import pytest
from fixtures import every_datatype_columns, organized_columns, xyz_columns
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer

from aftershock.pipeline.pointcloud2 import (
    POINTCLOUD2_MSGDEF,
    POSE_STAMPED_MSGDEF,
    NoXYZError,
    PointFieldType,
    columns_to_scan,
    decode_pointcloud2,
    encode_pointcloud2,
    pose_stamped_message,
    pose_to_matrix,
    serialize_pointcloud2,
    serialize_pose_stamped,
    times_relative_s,
)

STAMP = 1_700_000_000_250_000_000


def as_msg(d: dict) -> SimpleNamespace:
    """An encoded dict seen the way a decoder presents it (attributes)."""
    return SimpleNamespace(**{**d, "fields": [SimpleNamespace(**f) for f in d["fields"]]})


def roundtrip(cols: dict, **kw) -> dict[str, np.ndarray]:
    return decode_pointcloud2(as_msg(encode_pointcloud2(cols, stamp_ns=STAMP, frame_id="lidar", **kw))).columns


@pytest.mark.parametrize("big_endian", [False, True])
@pytest.mark.parametrize(
    ("point_step", "row_padding", "height"), [(None, 0, 1), (160, 0, 1), (None, 7, 4), (150, 13, 5)]
)
def test_every_datatype_roundtrips(big_endian: bool, point_step: int | None, row_padding: int, height: int) -> None:
    cols = every_datatype_columns(40, seed=3)
    out = roundtrip(cols, big_endian=big_endian, point_step=point_step, row_padding=row_padding, height=height)
    assert set(out) == set(cols)
    for name, arr in cols.items():
        assert out[name].dtype == arr.dtype.newbyteorder("="), name
        assert out[name].shape == arr.shape, name
        np.testing.assert_array_equal(out[name], arr, err_msg=name)


def test_encoder_declares_fields_from_dtypes() -> None:
    msg = encode_pointcloud2(every_datatype_columns(5), stamp_ns=STAMP, frame_id="f", height=1)
    kinds = {f["name"]: (PointFieldType(f["datatype"]), f["count"]) for f in msg["fields"]}
    assert kinds["i8"] == (PointFieldType.INT8, 1)
    assert kinds["u32"] == (PointFieldType.UINT32, 1)
    assert kinds["x"] == (PointFieldType.FLOAT64, 1)
    assert kinds["normal"] == (PointFieldType.FLOAT32, 3)
    assert msg["point_step"] == sum(PointFieldType(f["datatype"]).numpy.itemsize * f["count"] for f in msg["fields"])
    assert msg["header"]["stamp"] == {"sec": 1_700_000_000, "nanosec": 250_000_000}


def test_fields_read_by_offset_not_order() -> None:
    """A driver may declare fields out of memory order and leave gaps; offsets decide."""
    rec = np.zeros(
        3, dtype=np.dtype({"names": ["z", "x", "y"], "formats": ["<f4"] * 3, "offsets": [12, 0, 4], "itemsize": 20})
    )
    rec["x"], rec["y"], rec["z"] = [1, 2, 3], [4, 5, 6], [7, 8, 9]
    fields = [SimpleNamespace(name=n, offset=o, datatype=7, count=1) for n, o in (("z", 12), ("x", 0), ("y", 4))]
    msg = SimpleNamespace(
        height=1, width=3, fields=fields, is_bigendian=False, point_step=20, row_step=60, data=rec.tobytes()
    )
    cols = decode_pointcloud2(msg).columns
    np.testing.assert_array_equal(cols["z"], [7, 8, 9])
    np.testing.assert_array_equal(cols["x"], [1, 2, 3])


def test_short_data_and_bad_field_are_errors() -> None:
    msg = as_msg(encode_pointcloud2(xyz_columns(10), stamp_ns=STAMP, frame_id="l"))
    msg.data = msg.data[:-1]
    with pytest.raises(ValueError, match="data holds"):
        decode_pointcloud2(msg)
    msg = as_msg(encode_pointcloud2(xyz_columns(10), stamp_ns=STAMP, frame_id="l"))
    msg.fields[0].datatype = 42
    with pytest.raises(ValueError, match="unknown PointField datatype"):
        decode_pointcloud2(msg)


def test_invalid_rows_drop_with_every_per_point_array() -> None:
    cols = organized_columns(8, 16, zero_rows=[2, 5], nan_points=7, seed=1)
    cols["class_id"] = np.arange(128, dtype=np.uint16)
    cols["instance_id"] = np.arange(128, dtype=np.uint32) + 1000
    cols["ring"] = np.repeat(np.arange(8, dtype=np.uint16), 16)
    scan = columns_to_scan(roundtrip(cols, height=8), stamp_ns=STAMP)
    assert scan is not None
    keep = np.isfinite(cols["x"]) & ~np.isin(np.arange(128) // 16, [2, 5])
    assert len(scan) == keep.sum() < 128 - 32  # the zero rows and the NaN points outside them are gone
    np.testing.assert_array_equal(scan.class_ids, np.arange(128)[keep])
    np.testing.assert_array_equal(scan.instance_ids, np.arange(128)[keep] + 1000)
    np.testing.assert_array_equal(scan.ring, (np.arange(128) // 16)[keep])
    np.testing.assert_allclose(scan.points[:, 1], cols["y"][keep])
    np.testing.assert_allclose(scan.times, cols["t"][keep] * 1e-9)
    np.testing.assert_allclose(scan.intensity, cols["intensity"][keep])
    assert scan.has_ground_truth


def test_all_invalid_is_none_and_missing_xyz_raises() -> None:
    cols = organized_columns(2, 4, zero_rows=[0, 1])
    assert columns_to_scan(cols, stamp_ns=STAMP) is None
    with pytest.raises(NoXYZError, match="no x/y/z"):
        columns_to_scan({"x": np.ones(3, np.float32), "intensity": np.ones(3, np.float32)}, stamp_ns=STAMP)


def test_time_conventions() -> None:
    n = 5
    offsets = np.linspace(0, 0.09, n)
    # Ouster `t` and Livox `offset_time`: u32 ns after the stamp
    np.testing.assert_allclose(times_relative_s((offsets * 1e9).astype(np.uint32), "t", STAMP), offsets, atol=1e-9)
    # Velodyne `time`: f32 s, relative (may be negative: the stamp is the end of the sweep)
    rel = (offsets - 0.1).astype(np.float32)
    np.testing.assert_allclose(times_relative_s(rel, "time", STAMP), rel, atol=1e-7)
    # `timestamp`: f64 absolute seconds since the epoch
    absolute = STAMP * 1e-9 + offsets
    np.testing.assert_allclose(times_relative_s(absolute, "timestamp", STAMP), offsets, atol=1e-6)
    # `timestamp` that is in fact relative (small values) stays as it is
    np.testing.assert_allclose(times_relative_s(offsets, "timestamp", STAMP), offsets)
    # absolute ns in an integer field
    abs_ns = np.int64(STAMP) + np.round(offsets * 1e9).astype(np.int64)
    np.testing.assert_allclose(times_relative_s(abs_ns, "t", STAMP), offsets, atol=1e-9)


@pytest.mark.parametrize("name", ["t", "time", "timestamp", "offset_time", "Time"])
def test_time_field_names_found(name: str) -> None:
    cols = xyz_columns(6)
    del cols["t"]
    cols[name] = np.linspace(0, 0.05, 6).astype(np.float32)
    scan = columns_to_scan(cols, stamp_ns=STAMP)
    assert scan is not None and scan.times is not None
    np.testing.assert_allclose(scan.times, np.linspace(0, 0.05, 6), atol=1e-7)


def test_colors_packed_and_separate() -> None:
    cols = xyz_columns(3)
    rgb = np.array([[255, 0, 0], [0, 128, 0], [1, 2, 3]], np.uint8)
    packed = (rgb[:, 0].astype(np.uint32) << 16) | (rgb[:, 1].astype(np.uint32) << 8) | rgb[:, 2]
    scan = columns_to_scan(roundtrip(cols | {"rgb": packed.view(np.float32)}), stamp_ns=STAMP)
    np.testing.assert_array_equal(scan.colors, rgb)
    scan = columns_to_scan(roundtrip(cols | {"rgba": packed | np.uint32(0xFF000000)}), stamp_ns=STAMP)
    np.testing.assert_array_equal(scan.colors, rgb)
    sep = {"r": rgb[:, 0], "g": rgb[:, 1], "b": rgb[:, 2]}
    np.testing.assert_array_equal(columns_to_scan(roundtrip(cols | sep), stamp_ns=STAMP).colors, rgb)
    unit = {"red": rgb[:, 0] / 255.0, "green": rgb[:, 1] / 255.0, "blue": rgb[:, 2] / 255.0}
    np.testing.assert_array_equal(columns_to_scan(cols | unit, stamp_ns=STAMP).colors, rgb)


def test_messages_through_mcap_ros2_and_fast_cdr_agree() -> None:
    cols = every_datatype_columns(30, seed=5)
    msg = encode_pointcloud2(cols, stamp_ns=STAMP, frame_id="lidar", height=3, point_step=150, row_padding=5)
    pose = np.eye(4)
    pose[:3, :3] = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    pose[:3, 3] = [1.0, -2.0, 0.5]
    pmsg = pose_stamped_message(pose, STAMP)
    buf = io.BytesIO()
    w = Writer(buf)
    w.write_message("/pc", w.register_msgdef("sensor_msgs/msg/PointCloud2", POINTCLOUD2_MSGDEF), msg, log_time=STAMP)
    w.write_message(
        "/pose", w.register_msgdef("geometry_msgs/msg/PoseStamped", POSE_STAMPED_MSGDEF), pmsg, log_time=STAMP
    )
    w.finish()
    buf.seek(0)
    seen = set()
    for _, channel, message, decoded in make_reader(buf, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
        seen.add(channel.topic)
        if channel.topic == "/pc":
            assert message.data == serialize_pointcloud2(msg)
            out = decode_pointcloud2(decoded).columns
            for name, arr in cols.items():
                np.testing.assert_array_equal(out[name], arr)
        else:
            assert message.data == serialize_pose_stamped(pmsg)
            np.testing.assert_allclose(pose_to_matrix(decoded.pose), pose, atol=1e-12)
    assert seen == {"/pc", "/pose"}
