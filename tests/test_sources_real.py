"""The real LiDAR logs in ../shared/data/lidar: counts, fields and decoded values checked against the raw messages."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from aftershock import sources
from aftershock.sources.inspect import inspect

VLP16 = "velodyne_vlp16_indoor.mcap"
OS128 = "ouster_os1_128_outdoor.mcap"
OS64_ROS1 = "ouster_os1_64_ros1.mcap"


def raw_messages(path: Path, topic: str) -> list:
    """The decoded messages, by the mcap support libraries (not by our code)."""
    from mcap_ros1.decoder import DecoderFactory as Ros1
    from mcap_ros2.decoder import DecoderFactory as Ros2

    with path.open("rb") as fh:
        reader = make_reader(fh, decoder_factories=[Ros2(), Ros1()])
        return [(m.log_time, d) for _, _, m, d in reader.iter_decoded_messages(topics=[topic])]


def unpack_point(msg, index: int, names: list[str]) -> dict[str, float]:
    """One point's fields with `struct`, straight from the message bytes."""
    fmt = {1: "b", 2: "B", 3: "h", 4: "H", 5: "i", 6: "I", 7: "f", 8: "d"}
    row, col = divmod(index, msg.width)
    base = row * msg.row_step + col * msg.point_step
    out = {}
    for f in msg.fields:
        if f.name in names:
            out[f.name] = struct.unpack_from(
                ("<" if not msg.is_bigendian else ">") + fmt[f.datatype], msg.data, base + f.offset
            )[0]
    return out


def raw_xyz(msg) -> np.ndarray:
    """(N, 3) float32 x y z of every point, by strides over the message bytes (rows may be padded)."""
    offsets = {f.name: f.offset for f in msg.fields}
    buf = np.frombuffer(msg.data, np.uint8)
    out = np.empty((msg.height, msg.width, 3), np.float32)
    for k, name in enumerate("xyz"):
        out[:, :, k] = np.ndarray((msg.height, msg.width), "<f4", buf, offsets[name], (msg.row_step, msg.point_step))
    return out.reshape(-1, 3)


def check_against_messages(path: Path, topic: str, time_field: str, time_scale: float) -> list:
    scans = list(sources.open(path))
    msgs = raw_messages(path, topic)
    assert len(scans) == len(msgs)
    rng = np.random.default_rng(0)
    for scan, (log_time, msg) in zip(scans, msgs, strict=True):
        assert scan.log_time_ns == log_time
        stamp = msg.header.stamp
        expected_stamp = stamp.to_nsec() if hasattr(stamp, "to_nsec") else stamp.sec * 10**9 + stamp.nanosec
        assert scan.stamp_ns == expected_stamp
        assert scan.frame_id == msg.header.frame_id and scan.topic == topic
        xyz = raw_xyz(msg)
        ok = np.isfinite(xyz).all(1) & (xyz != 0).any(1)
        assert len(scan) == ok.sum() > 0
        position = np.cumsum(ok) - 1  # where raw point i sits among the valid ones
        for i in rng.choice(np.flatnonzero(ok), 25, replace=False):
            full = unpack_point(msg, int(i), ["x", "y", "z", "intensity", time_field])
            j = position[i]
            np.testing.assert_allclose(scan.points[j], [full["x"], full["y"], full["z"]], rtol=1e-6)
            assert scan.intensity[j] == pytest.approx(full["intensity"], rel=1e-6)
            assert scan.times[j] == pytest.approx(full[time_field] * time_scale, abs=1e-9)
    return scans


def test_velodyne_vlp16(lidar_dir: Path) -> None:
    scans = check_against_messages(lidar_dir / VLP16, "/velodyne_points", "time", 1.0)
    assert len(scans) == 4
    assert all(14_000 < len(s) < 15_500 for s in scans)
    for s in scans:
        assert set(np.unique(s.ring).tolist()) == set(range(1, 16))  # this recording has no return on ring 0
        assert s.times.min() >= 0 and s.times.max() <= 0.101  # a 10 Hz sweep, offsets from the stamp
    assert [s.stamp_ns - scans[0].stamp_ns for s in scans][1] == pytest.approx(100_000_000, abs=2_000_000)


def test_ouster_os1_128_organized_with_zero_rows(lidar_dir: Path) -> None:
    scans = check_against_messages(lidar_dir / OS128, "/ouster/points", "t", 1e-9)
    assert len(scans) == 3
    assert all(len(s) < 128 * 1024 for s in scans)  # the no-return zeros are gone
    assert all(len(s) > 100_000 for s in scans)
    for s in scans:
        assert s.ring.max() == 127 and s.times.max() <= 0.1


def test_third_party_ros1_mcap(lidar_dir: Path) -> None:
    path = lidar_dir / OS64_ROS1
    scans = check_against_messages(path, "/os1_cloud_node/points", "t", 1e-9)
    assert len(scans) == 2
    assert all(40_000 < len(s) < 64 * 2048 for s in scans)
    # the header stamps (sensor time) and log times differ in this recording; both are kept
    assert scans[0].log_time_ns != scans[0].stamp_ns


def test_info_on_real_logs(lidar_dir: Path) -> None:
    vlp = inspect(lidar_dir / VLP16)
    assert [(t.name, t.type, t.count) for t in vlp.topics] == [("/velodyne_points", "sensor_msgs/msg/PointCloud2", 4)]
    pc = vlp.point_clouds[0]
    assert [(f.name, f.datatype) for f in pc.fields] == [
        ("x", "FLOAT32"), ("y", "FLOAT32"), ("z", "FLOAT32"), ("intensity", "FLOAT32"),
        ("time", "FLOAT32"), ("column", "UINT16"), ("ring", "UINT8"), ("return_type", "UINT8"),
    ]  # fmt: skip
    assert pc.per_point_time == "time" and pc.time_convention == "s_offset"
    assert not pc.ground_truth_classes and vlp.pose_topics == []
    assert vlp.duration_s == pytest.approx(0.300, abs=0.01)

    os1 = inspect(lidar_dir / OS128)
    pc = os1.point_clouds[0]
    assert pc.organized == "128 x 1024" and pc.scans == 3 and pc.per_point_time == "t"
    assert pc.points_min <= pc.points_median <= pc.points_max < 128 * 1024
    assert pc.invalid_points_total == 3 * 128 * 1024 - pc.points_total

    ros1 = inspect(lidar_dir / OS64_ROS1)
    counts = {t.name: (t.type, t.count) for t in ros1.topics}
    assert counts["/os1_cloud_node/points"] == ("sensor_msgs/PointCloud2", 2)
    assert counts["/os1_node/lidar_packets"] == ("ouster_ros/PacketMsg", 206)
    assert counts["/os1_cloud_node/imu"] == ("sensor_msgs/Imu", 17)
    assert counts["/rosout"] == ("rosgraph_msgs/Log", 12)  # two channels on one topic, counted together
    assert [p.topic for p in ros1.point_clouds] == ["/os1_cloud_node/points"]


def test_pcd_room_scans_match_open3d(lidar_dir: Path) -> None:
    import open3d as o3d

    scans = list(sources.open(str(lidar_dir / "room_scan*.pcd")))
    assert [len(s) for s in scans] == [112_586, 112_624]
    ref = o3d.t.io.read_point_cloud(str(lidar_dir / "room_scan1.pcd")).point.positions.numpy()
    np.testing.assert_array_equal(scans[0].points, ref.astype(np.float64))
    extent = scans[0].points.max(0) - scans[0].points.min(0)
    assert extent[0] == pytest.approx(29, abs=3) and extent[2] == pytest.approx(3, abs=1)
